"""Model predictive control of a multirotor on the full quaternion model of the physics core.

The controller follows a :class:`~uavturb.sim.core.signals.Reference` (position, velocity,
acceleration and yaw in time) with the rotor speeds as inputs and their bounds
``0 <= Omega_i <= Omega_max`` as constraints, on the one CasADi model of
:mod:`uavturb.physics.dynamics` (the paper's eq. 1: state ``p, q (w, x, y, z), v, w``,
13 values). It is a *real-time iteration* (RTI) scheme in condensed, single-shooting form:

1. **Warm start**: the input plan ``U`` of the previous solve, shifted by one step (the
   last step repeated); the first solve starts from the hover speeds.
2. **Linearisation** about that plan: one CasADi call (``Dynamics.rk4`` of the physics
   core, ``substeps`` RK4 steps per MPC step, and its Jacobians ``A_k = dx_{k+1}/dx_k``,
   ``B_k = dx_{k+1}/du_k``, rolled out along the horizon by ``mapaccum``) gives the nominal
   states ``x̄_1..x̄_N`` from the measured state; the condensed sensitivities
   ``G = dX/dU`` follow by the recursion ``G_k = A_k G_{k-1} + [0 .. B_k .. 0]``.
3. **QP** in the input change ``δU`` (``4N`` values for a quadrotor)::

       min  sum_k |x̄_k + G_k δU - x_ref,k|^2_Q  (terminal node: Q * terminal)
          + sum_k |u_k - u_ref,k|^2_R + sum_k |u_k - u_{k-1}|^2_S
       s.t. 0 <= u_k <= 1       (u = Omega / Omega_max)

   solved exactly by a primal-dual active-set method for box constraints (:func:`box_qp`,
   warm-started with the previous active set; typically 1-3 linear solves of size ``4N``).
   One QP per control step (RTI: one Gauss-Newton iteration, the next starts from its result).
4. **Reference** on the horizon: ``p, v`` and yaw from the reference; the attitude ``q_ref``
   from differential flatness (thrust axis along ``a + g e_z``, heading the yaw), hover-like
   rotor speeds ``u_ref`` carrying ``m |a + g e_z|``; body rates towards zero.
5. **Offset-free**: an external force estimate ``f̂`` [N, W] (what the model does not know:
   ground effect, wind...) enters the model as ``f_ext``; it is updated every step from the
   velocity prediction error, ``f̂ <- f̂ + gain m (v - v_pred) / dt``, and bounded.

The first input is applied (zero-order hold) until the next update, ``dt`` later (the
MPC runs slower than the physics: 25 Hz by default, physics at 200 Hz in
:func:`~uavturb.sim.dataset.flying.fly_trajectory`).

Timing: :class:`MPCController` records every update's wall time in ``solve_times`` [s];
``uavturb bench flights`` prints them (:func:`uavturb.bench.flights.mpc_update_times`).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from uavturb.errors import InputError
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY, IDX_Q, IDX_W, N_STATE, dynamics_for, physical_params
from uavturb.physics.vehicle import Vehicle
from uavturb.sim.core.signals import Reference

__all__ = ["MPCWeights", "MPCController", "box_qp", "flat_attitude"]


@dataclass(frozen=True)
class MPCWeights:
    """Cost weights (per squared unit), for a reference-tracking MPC.

    Attributes
    ----------
    position : 1/m^2, horizontal position error
    height : 1/m^2, vertical position error
    velocity : s^2/m^2
    attitude : -, quaternion error ``|q - q_ref|^2`` (yaw tracking lives here)
    rates : s^2/rad^2, body rates
    input : -, ``|u - u_ref|^2`` with ``u = Omega / Omega_max``
    input_rate : -, ``|u_k - u_{k-1}|^2``
    terminal : -, factor on the state weights at the last node
    """

    position: float = 400.0
    height: float = 800.0
    velocity: float = 20.0
    attitude: float = 50.0
    rates: float = 0.5
    input: float = 2.0
    input_rate: float = 5.0
    terminal: float = 5.0


def box_qp(H: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray, active: np.ndarray | None = None,
           max_iter: int = 30) -> tuple[np.ndarray, np.ndarray, int]:
    """``min 1/2 x'Hx + g'x`` s.t. ``lb <= x <= ub`` by the primal-dual active-set method
    (Hintermüller, Ito & Kunisch 2003) for a positive definite ``H``.

    Parameters
    ----------
    H : (n, n) positive definite
    g, lb, ub : (n,)
    active : (n,) int8 warm start, ``-1`` at the lower bound, ``+1`` at the upper, ``0`` free
    max_iter : int

    Returns
    -------
    x : (n,) the minimiser (exact when converged)
    active : (n,) int8, the final active set
    iterations : int, linear solves used; ``max_iter + 1`` when the active-set iteration did
        not converge (it can cycle when many bounds are active) and the QP was solved by
        CasADi's ``qrqp`` active-set solver instead
    """
    n = len(g)
    act = np.zeros(n, np.int8) if active is None else active.astype(np.int8).copy()
    x = np.zeros(n)
    for it in range(1, max_iter + 1):
        lo, hi = act < 0, act > 0
        free = ~(lo | hi)
        x = np.where(lo, lb, np.where(hi, ub, 0.0))
        if free.any():
            rhs = -(g[free] + H[np.ix_(free, ~free)] @ x[~free])
            Hf = H[np.ix_(free, free)]
            try:
                x[free] = np.linalg.solve(Hf, rhs)
            except np.linalg.LinAlgError:
                x[free] = np.linalg.lstsq(Hf, rhs, rcond=None)[0]
        lam = -(H @ x + g)  # multiplier: > 0 pushes up (upper bound active), < 0 down
        new = np.zeros(n, np.int8)
        new[(x + lam < lb) | (lo & (lam <= 0))] = -1
        new[(x + lam > ub) | (hi & (lam >= 0))] = 1
        new[(x < lb)] = -1
        new[(x > ub)] = 1
        if np.array_equal(new, act):
            return x, act, it
        act = new
    sol = _qrqp(n)(h=H, g=g, lbx=lb, ubx=ub)
    x = np.clip(np.asarray(sol["x"]).ravel(), lb, ub)
    act = np.where(x <= lb + 1e-12, -1, np.where(x >= ub - 1e-12, 1, 0)).astype(np.int8)
    return x, act, max_iter + 1


@lru_cache(maxsize=8)
def _qrqp(n: int) -> ca.Function:
    """CasADi's ``qrqp`` for a dense ``n``-variable box-constrained QP (the fallback of :func:`box_qp`)."""
    return ca.conic("box_qp", "qrqp", {"h": ca.Sparsity.dense(n, n), "a": ca.Sparsity(0, n)},
                    {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False})


def flat_attitude(acc: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Attitudes ``(K, 4)`` (w, x, y, z, body to world) whose thrust axis ``R e_z`` lies along
    ``acc + g e_z`` and whose heading is ``yaw`` [rad]: ``q = q_yaw ∘ q_tilt`` with the
    shortest rotation ``q_tilt`` from ``e_z`` to the thrust axis seen in the yawed frame.

    Parameters
    ----------
    acc : (K, 3) m/s^2, acceleration in W
    yaw : (K,) rad
    """
    acc = np.atleast_2d(acc)
    yaw = np.atleast_1d(yaw)
    b3 = acc + np.array([0.0, 0.0, GRAVITY])
    b3 /= np.linalg.norm(b3, axis=1, keepdims=True)
    c, s = np.cos(yaw), np.sin(yaw)
    bx = c * b3[:, 0] + s * b3[:, 1]  # b3 in the yawed frame
    by = -s * b3[:, 0] + c * b3[:, 1]
    bz = b3[:, 2]
    qt = np.stack([1.0 + bz, -by, bx, np.zeros_like(bz)], axis=1)
    qt /= np.linalg.norm(qt, axis=1, keepdims=True)
    ch, sh = np.cos(yaw / 2), np.sin(yaw / 2)
    # q_yaw ∘ q_tilt with q_yaw = (ch, 0, 0, sh)
    w = ch * qt[:, 0] - sh * qt[:, 3]
    x = ch * qt[:, 1] - sh * qt[:, 2]
    y = ch * qt[:, 2] + sh * qt[:, 1]
    z = ch * qt[:, 3] + sh * qt[:, 0]
    return np.stack([w, x, y, z], axis=1)


@lru_cache(maxsize=8)
def _linearisation(vehicle: Vehicle, horizon: int, dt: float, substeps: int, w_max: float) -> ca.Function:
    """``(x0 (13,), U (N_rot, H), P (9, H)) -> (X (13, H), A (13, 13 H), B (13, N_rot H))``:
    the nominal rollout and its step Jacobians along the horizon, on the physics core's
    ``Dynamics.rk4`` with inputs ``u = Omega / w_max`` and parameters ``P = [theta; f_ext]``."""
    dyn = dynamics_for(vehicle)
    n = vehicle.rotor_count
    x = ca.SX.sym("x", N_STATE)
    u = ca.SX.sym("u", n)
    p = ca.SX.sym("p", 9)
    h = dt / substeps
    xn = x
    for _ in range(substeps):
        xn = dyn.rk4(xn, u * w_max, p[:6], p[6:9], ca.DM.zeros(3), h)
    A = ca.densify(ca.jacobian(xn, x))  # dense: the buffered call writes full column-major blocks
    B = ca.densify(ca.jacobian(xn, u))
    step = ca.Function("mpc_step", [x, u, p], [xn, A, B])
    return step.mapaccum("mpc_roll", horizon)


def _cache_dir() -> Path:
    """Where compiled MPC functions are kept: ``$UAVTURB_CACHE/mpc`` or ``~/.cache/uavturb/mpc``."""
    root = os.environ.get("UAVTURB_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "uavturb")
    return Path(root) / "mpc"


@lru_cache(maxsize=8)
def _compiled(f: ca.Function) -> ca.Function | None:
    """``f`` as C code compiled by the system compiler (``cc``), loaded with ``casadi.external``;
    cached on disk by a hash of the generated source (written to a temporary name, then
    renamed: safe with parallel workers). ``None`` when there is no compiler or it fails
    (the caller keeps the CasADi virtual machine, about 6x slower)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    try:
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp) / "roll.c"
            cg = ca.CodeGenerator(src.name, {"with_header": False})
            cg.add(f)
            cg.generate(tmp + os.sep)
            digest = hashlib.sha256(src.read_bytes()).hexdigest()[:16]
            out = _cache_dir() / f"{f.name()}_{digest}.so"
            if not out.exists():
                out.parent.mkdir(parents=True, exist_ok=True)
                part = out.with_name(f"{out.stem}.{os.getpid()}.part.so")
                subprocess.run([cc, "-shared", "-fPIC", "-O1", str(src), "-o", str(part)], check=True,
                               capture_output=True, timeout=300)
                os.replace(part, out)
        return ca.external(f.name(), str(out))
    except (OSError, subprocess.SubprocessError, RuntimeError):
        return None


@dataclass
class _Horizon:
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    yaw: np.ndarray


class MPCController:
    """Real-time-iteration MPC following a reference (see the module docstring).

    Parameters
    ----------
    vehicle : Vehicle with known constants
    reference : Reference to follow (sampled at ``t + k dt``, ``k = 1..horizon``)
    dt : s, control period = MPC step (default 0.04 s, 25 Hz)
    horizon : int, steps (default 12: 0.48 s)
    substeps : int, RK4 steps per MPC step in the prediction
    weights : MPCWeights
    max_rotor_speed : rad/s (default: the vehicle's, else 2.5 x hover speed)
    disturbance_gain : -, in ``(0, 1]``, rate of the external-force estimate (0: off)
    disturbance_limit : -, bound on each component of the estimate, as a fraction of ``m g``
    max_error : m, position targets are pulled to within this distance of the vehicle
    compile : compile the linearisation to C with the system compiler (cached on disk; about
        six times faster); falls back to CasADi's virtual machine when that fails

    Attributes
    ----------
    solve_times : list of float, s, wall time of every :meth:`update`
    qp_iterations : list of int, linear solves of every QP
    f_hat : (3,) N, current external-force estimate in W
    last_plan : (N_rot, horizon) rad/s, the last input plan
    last_prediction : (horizon, 13), predicted states of the last plan (linearised)
    """

    def __init__(self, vehicle: Vehicle, reference: Reference, dt: float = 0.04, horizon: int = 12,
                 substeps: int = 2, weights: MPCWeights = MPCWeights(), max_rotor_speed: float | None = None,
                 disturbance_gain: float = 0.3, disturbance_limit: float = 0.5, max_error: float = 0.3,
                 compile: bool = True):
        if horizon < 1 or substeps < 1 or dt <= 0:
            raise InputError("mpc", "horizon and substeps must be >= 1 and dt > 0")
        self.vehicle, self.reference = vehicle, reference
        self.dt, self.H, self.n = float(dt), int(horizon), vehicle.rotor_count
        self.theta = physical_params(vehicle)
        self.m = float(vehicle.mass)
        self.w_max = float(max_rotor_speed or vehicle.max_rotor_speed or 2.5 * vehicle.hover_speed())
        self.k_T = float(vehicle.thrust_coefficient)
        self.roll = _linearisation(vehicle, self.H, self.dt, int(substeps), self.w_max)
        self.compiled = False
        if compile:
            fast = _compiled(self.roll)
            if fast is not None:
                self.roll, self.compiled = fast, True
        # preallocated CasADi buffer: inputs and outputs are numpy arrays (column-major views)
        n_, H_ = self.n, self.H
        self._x_in, self._U_in, self._P_in = np.zeros(N_STATE), np.zeros((H_, n_)), np.zeros((H_, 9))
        self._X_out = np.zeros((H_, N_STATE))
        self._A_out = np.zeros((H_ * N_STATE, N_STATE))  # column-major (13, 13H) = row-major (13H, 13)
        self._B_out = np.zeros((H_ * n_, N_STATE))  # column-major (13, nH)
        self._buf, self._run = self.roll.buffer()
        for i, a in enumerate((self._x_in, self._U_in, self._P_in)):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate((self._X_out, self._A_out, self._B_out)):
            self._buf.set_res(i, memoryview(a))
        self.max_error = float(max_error)
        self.gain, self.f_lim = float(disturbance_gain), float(disturbance_limit) * self.m * GRAVITY
        w = weights
        q = np.zeros(N_STATE)
        q[0:2], q[2], q[IDX_Q], q[7:10], q[IDX_W] = w.position, w.height, w.attitude, w.velocity, w.rates
        Qd = np.tile(q, self.H)
        Qd[-N_STATE:] *= w.terminal
        self.Qd = Qd  # (13 H,) diagonal state weights
        nu = self.n * self.H
        D = np.eye(nu) - np.eye(nu, k=-self.n)  # u_k - u_{k-1}
        self.D = D
        self.R_fixed = w.input * np.eye(nu) + w.input_rate * D.T @ D
        self.w_in, self.w_rate = w.input, w.input_rate
        self.lb, self.ub = np.zeros(nu), np.ones(nu)
        self.reset()

    # --- state -----------------------------------------------------------------------------
    def reset(self, x: np.ndarray | None = None) -> None:
        """Forget the warm start, the active set and the force estimate."""
        u_h = np.sqrt(self.m * GRAVITY / (self.n * self.k_T)) / self.w_max
        self.U = np.full((self.n, self.H), u_h)
        self.u_prev = self.U[:, 0].copy()
        self.active = np.zeros(self.n * self.H, np.int8)
        self.f_hat = np.zeros(3)
        self._v_pred: np.ndarray | None = None
        self.solve_times: list[float] = []
        self.qp_iterations: list[int] = []
        self.last_plan = self.U * self.w_max
        self.last_prediction = np.zeros((self.H, N_STATE))
        self._grid: tuple[np.ndarray, ...] | None = None

    def _samples(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Reference ``p (H+1, 3), v (H+1, 3), a (H+1, 3), yaw (H+1,)`` at ``t + k dt``, ``k = 0..H``.

        Sampled once for the whole reference on the grid ``k dt`` (one vectorised call; the
        reference holds its last set-point after its end) and indexed when ``t`` lies on that
        grid, as in the flight loop; evaluated directly otherwise."""
        k = int(round(t / self.dt))
        if k >= 0 and abs(t - k * self.dt) < 1e-9:
            if self._grid is None:
                n = int(np.ceil(self.reference.duration / self.dt)) + 2
                sp = self.reference(np.arange(n) * self.dt)
                self._grid = (sp.p, sp.v, sp.a, sp.yaw)
            p, v, a, yaw = self._grid
            idx = np.minimum(np.arange(k, k + self.H + 1), len(yaw) - 1)
            return p[idx], v[idx], a[idx], yaw[idx]
        sp = self.reference(t + self.dt * np.arange(self.H + 1))
        return sp.p, sp.v, sp.a, sp.yaw

    def _targets(self, t: float, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State references ``(H, 13)`` and input references ``(n, H)`` at ``t + k dt``, ``k = 1..H``."""
        P, V, Acc, Yaw = self._samples(t)
        sp = _Horizon(P[1:], V[1:], Acc[1:], Yaw[1:])
        p_now = P[0]
        Xr = np.zeros((self.H, N_STATE))
        # reference governor: targets no farther than max_error from the vehicle (RTI linearises
        # about the last plan; far targets ask for tilts the linearisation cannot follow)
        # (the whole horizon is shifted towards the vehicle by the excess of the current error)
        e = p_now - x[0:3]
        norm = float(np.sqrt(e @ e))
        shift = e * (1.0 - self.max_error / norm) if norm > self.max_error else 0.0
        Xr[:, 0:3] = sp.p - shift
        Xr[:, 7:10] = sp.v
        qr = flat_attitude(sp.a, sp.yaw)
        # same hemisphere as the current attitude (q and -q are the same rotation)
        qr *= np.where(qr @ x[IDX_Q] < 0, -1.0, 1.0)[:, None]
        Xr[:, IDX_Q] = qr
        thrust = np.linalg.norm(self.m * (sp.a + np.array([0.0, 0.0, GRAVITY])) - self.f_hat, axis=1)
        ur = np.sqrt(np.maximum(thrust, 0.0) / (self.n * self.k_T)) / self.w_max
        return Xr, np.broadcast_to(ur, (self.n, self.H))

    def update(self, x: np.ndarray, t: float) -> np.ndarray:
        """One RTI step from the measured state ``x (13,)`` at time ``t`` [s]; returns the
        rotor speeds ``(N,)`` [rad/s] to hold for ``dt``."""
        t0 = time.perf_counter()
        x = np.asarray(x, float)
        if self._v_pred is not None and self.gain > 0:
            self.f_hat = np.clip(self.f_hat + self.gain * self.m * (x[7:10] - self._v_pred) / self.dt,
                                 -self.f_lim, self.f_lim)
        # warm start: shift the last plan
        Ubar = np.concatenate([self.U[:, 1:], self.U[:, -1:]], axis=1)
        self._x_in[:] = x
        self._U_in[:] = Ubar.T
        self._P_in[:, :6], self._P_in[:, 6:] = self.theta, self.f_hat
        self._run()
        Xb = self._X_out  # (H, 13): x_1 .. x_H
        A = self._A_out.reshape(self.H, N_STATE, N_STATE).transpose(0, 2, 1)  # A[k] = dx_{k+1}/dx_k
        B = self._B_out.reshape(self.H, self.n, N_STATE).transpose(0, 2, 1)  # B[k] = dx_{k+1}/du_k
        n, H = self.n, self.H
        nu = n * H
        G = np.zeros((H * N_STATE, nu))
        for k in range(H):
            r = slice(k * N_STATE, (k + 1) * N_STATE)
            if k:
                G[r, : k * n] = A[k] @ G[r.start - N_STATE: r.start, : k * n]
            G[r, k * n:(k + 1) * n] = B[k]
        Xr, Ur = self._targets(t, x)
        e = (Xb - Xr).ravel()
        QG = self.Qd[:, None] * G
        Hm = G.T @ QG + self.R_fixed
        ub_flat = Ubar.T.ravel()  # (nH,) step-major, matching G's columns
        ur_flat = np.asarray(Ur).T.ravel()
        d0 = np.zeros(nu)
        d0[:n] = self.u_prev
        gv = QG.T @ e + self.w_in * (ub_flat - ur_flat) + self.w_rate * self.D.T @ (self.D @ ub_flat - d0)
        dU, self.active, iters = box_qp(Hm, gv, self.lb - ub_flat, self.ub - ub_flat, self.active)
        U = np.clip(ub_flat + dU, 0.0, 1.0)
        self.U = U.reshape(H, n).T.copy()
        self.u_prev = self.U[:, 0].copy()
        pred = (Xb.ravel() + G @ (U - ub_flat)).reshape(H, N_STATE)
        self._v_pred = pred[0, 7:10]
        self.last_prediction = pred
        self.last_plan = self.U * self.w_max
        self.qp_iterations.append(iters)
        self.solve_times.append(time.perf_counter() - t0)
        return self.U[:, 0] * self.w_max


def track(vehicle: Vehicle, reference: Reference, duration: float, physics_rate: float = 400.0,
          f_ext: np.ndarray | None = None, x0: np.ndarray | None = None, **options: Any) -> dict[str, Any]:
    """Fly ``reference`` with the MPC on the plain dynamics (a constant external force ``f_ext``
    [N, W] optional), no scene: for tests and benchmarks.

    Returns ``{"t" (K,), "x" (K, 13), "omega" (K, N), "error" (K,) m, "solve_ms" (U,)}`` at
    the control rate.
    """
    ctrl = MPCController(vehicle, reference, **options)
    dyn = dynamics_for(vehicle)
    theta = physical_params(vehicle)
    every = int(round(physics_rate * ctrl.dt))
    h = ctrl.dt / every
    sp0 = reference(0.0)
    if x0 is None:
        x0 = np.zeros(N_STATE)
        x0[0:3] = sp0.p
        x0[IDX_Q] = quat.from_euler(0.0, 0.0, float(sp0.yaw))
    x = np.asarray(x0, float).copy()
    F = np.zeros(3) if f_ext is None else np.asarray(f_ext, float)
    K = int(round(duration / ctrl.dt))
    T, X, W = np.zeros(K), np.zeros((K, N_STATE)), np.zeros((K, vehicle.rotor_count))
    for k in range(K):
        t = k * ctrl.dt
        w = ctrl.update(x, t)
        T[k], X[k], W[k] = t, x, w
        for _ in range(every):
            x = dyn.step(x, w, theta, h, F)
    err = np.linalg.norm(X[:, 0:3] - reference(T).p, axis=1)
    return {"t": T, "x": X, "omega": W, "error": err, "solve_ms": np.asarray(ctrl.solve_times) * 1e3,
            "controller": ctrl}
