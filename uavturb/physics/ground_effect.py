"""Cheeseman-Bennett ground effect (Cheeseman & Bennett 1955; the paper's eq. "ground effect"),
Sanchez-Cuevas et al.'s multirotor law (2017; :func:`multirotor_thrust_ratio`), which adds the images
of the other rotors and the lift of the body, and an exponential decay in height
(:func:`exponential_thrust_ratio`, after He et al. 2019), whose extra thrust fades within a few rotor
radii instead of as ``1/d^2``.

Force on the vehicle, vertical, in newtons::

    f_a = phi(d, Omega) = k_T sum(Omega_i^2) rho / (1 - rho),   rho = mu (r / (4 d))^2

with ``d`` the height of the body origin over the surface below [m], ``r`` the rotor
radius [m] and ``mu`` [-] a coefficient that depends on the rotor count. It equals
``T rho / (1 - rho)`` with ``T = k_T sum(Omega^2)`` the rotor thrust (``effects.md``).

The law is singular at ``d = r sqrt(mu) / 4`` (``rho = 1``). The paper clips ``f_a`` to
0.1 mg (a weight of 0.1 milligram, 9.81e-7 N) when ``d`` falls under that value; we keep
that clip exactly (:data:`CLIP_FORCE_N`), as ``effects.md`` asks, although it makes the
law discontinuous there: just above the threshold the force grows without bound.

Identification (paper, "Predicting turbulences")::

    argmin_(alpha, beta) sum_t (f_a,t - alpha sum_i Omega_i,t^2 / (d_t^2 - beta))^2

with ``beta = mu r^2 / 16`` and ``alpha = k_T beta``. The paper writes ``sum_i Omega_i``
in its prediction formula and ``sum_i Omega_i^2`` in the identification: the law has
``Omega^2`` (thrust is quadratic in rotor speed), so we use ``Omega^2`` everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from uavturb.errors import InputError
from uavturb.physics.constants import AIR_DENSITY, GRAVITY

CLIP_FORCE_N = 0.1e-6 * GRAVITY  # N: the paper's clip value, 0.1 mg, as a weight


def rho(d: np.ndarray, mu: float, r: float) -> np.ndarray:
    """``rho = mu (r / (4 d))^2`` [-]; 0 where ``d`` is infinite (no surface)."""
    d = np.asarray(d, dtype=float)
    with np.errstate(divide="ignore"):
        return mu * (r / (4.0 * d)) ** 2


def min_height(mu: float, r: float) -> float:
    """Height [m] under which the law is clipped: ``r sqrt(mu) / 4``."""
    return r * np.sqrt(max(mu, 0.0)) / 4.0


def force_ratio(d: np.ndarray, mu: float, r: float) -> np.ndarray:
    """``rho / (1 - rho)`` [-], the ground-effect force per unit thrust; ``nan`` where clipped."""
    rh = rho(d, mu, r)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = rh / (1.0 - rh)
    return np.where(np.asarray(d, float) <= min_height(mu, r), np.nan, out)


def thrust_ratio(d: np.ndarray, mu: float, r: float) -> np.ndarray:
    """Cheeseman-Bennett ``T_IGE / T_OGE = 1 / (1 - rho)`` [-], ``rho = mu (r / (4 d))^2``.

    Parameters
    ----------
    d : (K,) rotor-plane height over the surface below [m] (``inf`` where none: ratio 1)
    mu : coefficient [-]
    r : rotor radius [m]

    Returns
    -------
    (K,) thrust per rotor speed squared over its value far from the surface; ``nan`` where the law
    is clipped (``d <= r sqrt(mu) / 4``, :func:`min_height`).
    """
    return 1.0 + force_ratio(d, mu, r)


def rotor_spacing(arm_length: float, rotor_count: int) -> tuple[float, float]:
    """Distances [m] the multirotor law (:func:`multirotor_thrust_ratio`) needs, for ``rotor_count``
    rotors evenly spaced on a circle of radius ``arm_length`` [m] around the centre.

    Returns
    -------
    spacing : between the centres of adjacent rotors, ``2 l sin(pi / n)`` (``sqrt(2) l`` on a quadrotor)
    opposite : between the centres of opposite rotors, ``2 l`` (Sanchez-Cuevas et al.'s ``b``)
    """
    if arm_length <= 0 or rotor_count < 2:
        raise InputError("ground effect", f"arm_length must be > 0 m and rotor_count >= 2, got {arm_length} "
                                          f"and {rotor_count}")
    return 2.0 * arm_length * float(np.sin(np.pi / rotor_count)), 2.0 * arm_length


def hover_induced_velocity(mass: float, rotor_count: int, rotor_radius: float, air_density: float = AIR_DENSITY
                           ) -> float:
    """The rotors' induced velocity in hover [m/s], momentum theory: ``sqrt(m g / (2 rho N pi r^2))`` for ``N``
    rotors of radius ``r`` [m] carrying ``mass`` [kg] in air of density ``air_density`` (``rho``) [kg/m^3]
    (Leishman, *Principles of Helicopter Aerodynamics*, 2nd ed., eq. 2.15). A Crazyflie's (32 g, r = 2.31 cm) is
    4.4 m/s; a 1.5 kg quadrotor's with 5-inch-radius rotors 5.5 m/s. Axial flight at a fair share of it changes the
    thrust per rotor speed squared (the rotor's inflow changes)."""
    if mass <= 0 or rotor_count < 1 or rotor_radius <= 0 or air_density <= 0:
        raise InputError("rotor inflow", f"mass, rotor_count, rotor_radius and air density must be > 0, got "
                                         f"{mass}, {rotor_count}, {rotor_radius} and {air_density}")
    return float(np.sqrt(mass * GRAVITY / (2.0 * air_density * rotor_count * np.pi * rotor_radius**2)))


def _image_term(z: np.ndarray, r: float, s: float) -> np.ndarray:
    """``r^2 z / sqrt((s^2 + 4 z^2)^3)`` [-]: twice the upwash a rotor's ground image at horizontal
    distance ``s`` [m] induces at a rotor ``z`` [m] over the ground, per its own induced velocity."""
    with np.errstate(invalid="ignore", over="ignore"):
        return r**2 * z / np.sqrt((s**2 + 4.0 * z**2) ** 3)


def multirotor_terms(z: np.ndarray, r: float, spacing: float, opposite: float) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of Sanchez-Cuevas et al.'s denominator: ``(rotors, body)`` with
    ``T_IGE / T_OGE = 1 / (1 - rotors - K_b body)`` (see :func:`multirotor_thrust_ratio`).

    ``rotors = (r/(4z))^2 + r^2 z/sqrt((d^2+4z^2)^3) + (r^2 z/2)/sqrt((2d^2+4z^2)^3)``: the rotor's own
    image, the two adjacent rotors' images (at ``d``) and the diagonal one's (at ``sqrt(2) d``);
    ``body = 2 r^2 z / sqrt((b^2+4z^2)^3)``. Both 0 where ``z`` is infinite.
    """
    z = np.asarray(z, dtype=float)
    far = ~np.isfinite(z)
    zz = np.where(far, 1.0, z)
    with np.errstate(divide="ignore"):
        rotors = (r / (4.0 * zz)) ** 2 + _image_term(zz, r, spacing) + 0.5 * _image_term(zz, r, np.sqrt(2.0) * spacing)
    body = 2.0 * _image_term(zz, r, opposite)
    return np.where(far, 0.0, rotors), np.where(far, 0.0, body)


def multirotor_thrust_ratio(z: np.ndarray, K_b: float, r: float, spacing: float, opposite: float) -> np.ndarray:
    """Sanchez-Cuevas, Heredia & Ollero's multirotor ground effect, ``T_IGE / T_OGE`` [-].

    Source: P. Sanchez-Cuevas, G. Heredia, A. Ollero, "Characterization of the Aerodynamic Ground Effect
    and Its Influence in Multirotor Control", Int. J. Aerospace Eng. 2017, article 1823056 (doi
    10.1155/2017/1823056), their quadrotor ground-effect model (section "ground effect in multirotors";
    quoted as eq. 7 by Kan et al., IEEE RA-L 2019)::

        T_IGE/T_OGE = 1 / (1 - (R/(4z))^2 - R^2 z/sqrt((d^2+4z^2)^3) - (R^2 z/2)/sqrt((2d^2+4z^2)^3)
                             - 2 R^2 z K_b/sqrt((b^2+4z^2)^3))

    Cheeseman & Bennett's method of images extended to the images of the other three rotors of an
    X quadrotor (two adjacent at ``d``, one diagonal at ``sqrt(2) d``) and to the lift of the body
    in the flows of the rotors meeting under it (the "fountain"), weighted by the empirical body-lift
    coefficient ``K_b``. Far from the ground it behaves as Cheeseman-Bennett with
    ``mu = 4 (1 + K_b)``; near it, it rises less steeply than Cheeseman-Bennett for the same far
    reach. The paper writes it for quadrotors: other rotor counts use the same terms with
    ``d`` the adjacent spacing (:func:`rotor_spacing`), an approximation.

    Parameters
    ----------
    z : (K,) height of the rotor plane over the ground [m] (``inf`` where none: ratio 1)
    K_b : body-lift coefficient [-], fitted (implementations of the paper use 0.5-2)
    r : rotor radius ``R`` [m]
    spacing : distance between the centres of adjacent rotors ``d`` [m]
    opposite : distance between the centres of opposite rotors ``b`` [m] (``2 l`` for arm length ``l``)

    Returns
    -------
    (K,) ratio; ``nan`` at and under the pole (denominator <= 0), where the law does not hold.
    """
    rotors, body = multirotor_terms(z, r, spacing, opposite)
    den = 1.0 - rotors - K_b * body
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0.0, 1.0 / den, np.nan)


def exponential_thrust_ratio(d: np.ndarray, A: float, lam: float, r: float) -> np.ndarray:
    """``T_IGE / T_OGE = 1 + A exp(-d / (lam r))`` [-]: extra thrust decaying exponentially with height.

    He, Kou, Calaf & Leang (2019, ASME J. Dyn. Sys., Meas., Control 141(7) 071013) model a quadrotor's
    quasi-steady in-ground effect by an exponential in height; this is that shape with the decay length
    in rotor radii, so that one value compares across vehicles. Unlike the Cheeseman-Bennett law it stays
    finite at the surface (``1 + A``) and its tail falls faster than ``1/d^2``: measured multirotor
    curves that flatten near the floor and vanish within a few radii (Neural-Swarm's Crazyflies: ``lam``
    about 1.6 r) follow it where Cheeseman-Bennett's shape does not.

    Parameters
    ----------
    d : (K,) rotor-plane height over the surface below [m] (``inf`` where none: ratio 1)
    A : extra thrust share at the surface [-]
    lam : decay length [rotor radii]
    r : rotor radius [m]

    Returns
    -------
    (K,) thrust per rotor speed squared over its value far from the surface; ``nan`` where ``d <= 0``
    (the rotor plane at or under the surface) or ``lam <= 0``.
    """
    d = np.asarray(d, dtype=float)
    if not lam > 0 or not r > 0:
        return np.full(d.shape, np.nan)
    with np.errstate(over="ignore", invalid="ignore"):
        out = 1.0 + A * np.exp(-d / (lam * r))
    return np.where(d > 0, out, np.nan)


def phi(d: np.ndarray, thrust: np.ndarray, mu: float, r: float) -> np.ndarray:
    """Cheeseman-Bennett force [N] along world ``+z``.

    Parameters
    ----------
    d : (K,) height over the surface below [m] (``inf`` where none)
    thrust : (K,) rotor thrust ``T = k_T sum(Omega^2)`` [N]
    mu : coefficient [-]
    r : rotor radius [m]

    Returns
    -------
    (K,) force [N]; :data:`CLIP_FORCE_N` where ``d <= r sqrt(mu) / 4`` (the paper's clip).
    """
    ratio = force_ratio(d, mu, r)
    return np.where(np.isnan(ratio), CLIP_FORCE_N, np.asarray(thrust, float) * np.nan_to_num(ratio))


def phi_alpha_beta(d: np.ndarray, sum_omega2: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """The paper's identification form ``alpha sum(Omega^2) / (d^2 - beta)`` [N], clipped like :func:`phi`."""
    d2 = np.asarray(d, float) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        f = alpha * np.asarray(sum_omega2, float) / (d2 - beta)
    return np.where(d2 <= beta, CLIP_FORCE_N, np.where(np.isinf(d2), 0.0, f))


@dataclass(frozen=True)
class GroundEffectFit:
    """Identified ``(alpha, beta)`` and what they mean for a known rotor.

    Attributes
    ----------
    alpha : float
        ``k_T beta`` [N m^2/(rad/s)^2]
    beta : float
        ``mu r^2 / 16`` [m^2]
    rmse : float
        N, root mean square of the fit residual
    n : int
        samples used
    stderr_alpha, stderr_beta : float
        Standard errors [same units] from the fit's Jacobian, ``sigma^2 (J^T J)^-1`` with the
        residual variance ``sigma^2`` (white, independent residuals: a lower bound where they
        are correlated in time); ``nan`` when the flights do not separate ``alpha`` from
        ``beta`` (all at one height: only ``alpha / (d^2 - beta)`` is seen)
    """

    alpha: float
    beta: float
    rmse: float
    n: int
    stderr_alpha: float = float("nan")
    stderr_beta: float = float("nan")

    def mu(self, r: float) -> float:
        """``mu = 16 beta / r^2`` for rotor radius ``r`` [m]."""
        return 16.0 * self.beta / r**2

    def k_T(self) -> float:
        """``k_T = alpha / beta`` [N/(rad/s)^2]."""
        return self.alpha / self.beta

    def predict(self, d: np.ndarray, sum_omega2: np.ndarray) -> np.ndarray:
        return phi_alpha_beta(d, sum_omega2, self.alpha, self.beta)


def identify_alpha_beta(f_a: np.ndarray, d: np.ndarray, sum_omega2: np.ndarray) -> GroundEffectFit:
    """Fit ``(alpha, beta)`` by BFGS on the paper's least-squares objective.

    The start comes from the linearised problem ``f_a d^2 = alpha S + beta f_a`` (linear
    least squares); ``beta`` is kept inside ``(0, min d^2)`` by the change of variable
    ``beta = min(d^2) sigmoid(z)``, so BFGS runs unconstrained and never meets the pole.

    Parameters
    ----------
    f_a : (K,) measured vertical turbulence force [N]
    d : (K,) true heights over the surface below [m]
    sum_omega2 : (K,) ``sum_i Omega_i^2`` [rad^2/s^2]
    """
    f_a, d, S = (np.asarray(a, dtype=float).ravel() for a in (f_a, d, sum_omega2))
    if not (len(f_a) == len(d) == len(S)):
        raise InputError("ground effect fit", "f_a, d and sum_omega2 must have the same length")
    ok = np.isfinite(f_a) & np.isfinite(d) & np.isfinite(S) & (d > 0)
    if ok.sum() < 3:
        raise InputError("ground effect fit", "fewer than 3 valid samples")
    f_a, d, S = f_a[ok], d[ok], S[ok]
    d2 = d**2
    d2min = float(d2.min())

    A = np.stack([S, f_a], axis=1)
    (a0, b0), *_ = np.linalg.lstsq(A, f_a * d2, rcond=None)
    b0 = float(np.clip(b0, 1e-6 * d2min, 0.95 * d2min))
    a0 = float(a0) if a0 > 0 else float(np.mean(np.abs(f_a) * d2 / np.maximum(S, 1e-12)))
    a0 = max(a0, 1e-30)

    f_scale = max(float(np.sqrt(np.mean(f_a**2))), 1e-12)

    def unpack(z: np.ndarray) -> tuple[float, float]:
        alpha = a0 * np.exp(z[0])
        beta = d2min / (1.0 + np.exp(-z[1]))
        return alpha, beta

    def loss(z: np.ndarray) -> float:
        alpha, beta = unpack(z)
        r = (f_a - alpha * S / (d2 - beta)) / f_scale
        return float(np.mean(r**2))

    z0 = np.array([0.0, np.log(b0 / (d2min - b0))])
    res = minimize(loss, z0, method="BFGS", options={"gtol": 1e-12, "maxiter": 500})
    alpha, beta = unpack(res.x)
    resid = f_a - alpha * S / (d2 - beta)
    rmse = float(np.sqrt(np.mean(resid**2)))
    se_alpha, se_beta = _alpha_beta_stderr(resid, d2, S, alpha, beta)
    return GroundEffectFit(alpha=float(alpha), beta=float(beta), rmse=rmse, n=int(ok.sum()), stderr_alpha=se_alpha,
                           stderr_beta=se_beta)


def _alpha_beta_stderr(resid: np.ndarray, d2: np.ndarray, S: np.ndarray, alpha: float, beta: float
                       ) -> tuple[float, float]:
    """Standard errors of ``(alpha, beta)`` of ``f = alpha S / (d^2 - beta)`` from the Jacobian at the fit,
    ``nan`` where it is singular (every sample at one height)."""
    n = len(resid)
    if n <= 2:
        return float("nan"), float("nan")
    J = np.stack([S / (d2 - beta), alpha * S / (d2 - beta) ** 2], axis=1)
    scale = np.array([max(abs(alpha), 1e-300), max(abs(beta), 1e-300)])
    Js = J * scale  # relative parameters: a well-scaled J^T J
    JtJ = Js.T @ Js
    if np.linalg.cond(JtJ) > 1e12:
        return float("nan"), float("nan")
    cov = np.linalg.inv(JtJ) * float(resid @ resid) / (n - 2)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0)) * scale
    return float(se[0]), float(se[1])
