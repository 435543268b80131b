"""The translational model the gap finder fits, as regressors.

For each sample the measured total force on the vehicle in W is ``y = m R a_imu`` (IMU; the
state file's biases removed) or ``y = m (v_dot + g e_z)`` (MoCap). The model is::

    y = k_T S_eff (R e_z (1 - s t) + e_z (G(mu, d_down) + G(kappa, d_up)))    thrust, surface effects, battery
        + m R b                                                            accelerometer bias left (body; IMU rows only)
        - k_d Wsum R [v_B,x, v_B,y, 0]                                     rotor_drag
        - c_d |v| v                                                        body_drag
        + (f_x, f_y, 0)                                                    wind

with ``S_eff = sum(w_lag(tau)^2)`` (``motor_lag``; ``w_lag = w`` when absent) and
``G(c, d) = rho/(1-rho)``, ``rho = c (r/(4 d))^2`` (``effects.md``, clipped like the paper's
ground effect). For fixed nonlinear parameters ``(mu, kappa, tau)`` it is linear in
``(k_T, k_T s, b, k_d, c_d, f_x, f_y)``: nonlinear parameters are profiled (grid, then a
bounded scalar search), linear ones solved by least squares.

Rows of recordings without an IMU (the residual comes from differentiated MoCap velocity)
have no accelerometer and so no bias term: its columns are zero there, and absent altogether
when no recording has an IMU (``recordings.md``: no accelerometer, no bias to estimate).
Which effects are nonlinear, act along the thrust or need a surface is read from the effect
registry (:data:`uavturb.physics.effects.EFFECTS`), never listed here.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from uavturb.sysid.nominal import ThrustLevels, moved_speeds, thrust_levels
from uavturb.numerics.filters import savgol_filter
from uavturb.numerics.threads import in_threads
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.effects import EFFECTS, EffectInputs, lag_rotor_speeds, lag_stretches
from uavturb.sysid.accelerometer import anchored_bias
from uavturb.sysid.command_lag import CommandLag
from uavturb.sysid.flight_data import FlightData
from uavturb.sysid.rotor_order import RotorOrder

#: rows in flight a recording needs to be fitted alone for the spread between recordings
#: (:func:`uavturb.gap.uncertainty.error_budget`; a minute of 3 Hz rotor telemetry over two flights has ~150): with
#: fewer its own fit is mostly noise, which read as a spread between sessions
MIN_ROWS = 100
#: rows in flight an analysis needs: fewer, and ``uavturb gap`` refuses the recordings in one line. A minute-long
#: log of a medium quadrotor whose ESCs report at 3 Hz, on its landing gear at both ends, holds 36-94 updates in
#: flight; refused at 100, simulated ones named the ground effect right alone (mu 2.15 +- 0.29, 1.78 +- 0.24,
#: 1.93 +- 0.26 for a truth of 2), as did two flights with 1-1.5 Hz rotor updates (mu 2.00 +- 0.54)
MIN_ANALYSIS_ROWS = 30
#: nonlinear parameter of each effect whose law is not linear in it, with its search bounds
#: (from the registry; a law with an ``amplitude`` is searched over its other parameter)
NONLINEAR = {n: (e.searched_param, *e.search) for n, e in EFFECTS.items() if e.search is not None}
#: surface laws with a linear amplitude: their coefficient's name in :func:`design` (``k_T*A``)
AMPLITUDE = {n: f"k_T*{e.amplitude}" for n, e in EFFECTS.items() if e.amplitude is not None}
#: laws that scale the thrust coefficient (``EffectSpec.thrust_factor``): their coefficient's name in :func:`design`
#: (``k_T*s``, ``k_T*k_V``)
THRUST_FACTOR = {n: f"k_T*{e.params[0]}" for n, e in EFFECTS.items() if e.thrust_factor is not None}


#: bytes of lagged rotor-speed sums kept per flight set (:meth:`GapData.S_lag`; 11 taus of a flight-hour at 200 Hz;
#: a 200 MB cap held a fifth of a 10^6-row flight's peak memory and saved no time measured)
LAG_CACHE_BYTES = 64 << 20
#: bytes of their block means kept per set of rows (a subset or the block means; 46 taus of a flight-hour at 25 Hz)
ROWS_LAG_CACHE_BYTES = 32 << 20
#: values of tau kept at most, whatever the flight's length: what the byte caps allow a flight-hour. Bytes alone had
#: let a 10-minute flight keep six times as many, a cache that grows with the flight up to its cap: the
#: benchmark's line through a 5- and a 10-minute measurement carried that growth to an hour (1.01 GB per
#: flight-hour for 0.89 GB with these caps, the same reports to the bit)
LAG_CACHE_TAUS, ROWS_LAG_CACHE_TAUS = 12, 46
#: rows from which the lagged sums' recordings are filtered on several threads, in all and per recording on
#: average: a minute at 100 Hz filters in a tenth of a millisecond, less than handing it to a thread costs. Twelve
#: one-minute flights (144,000 rows of 12,000) analysed in 9.5-10.1 s on one thread and 11.2-11.3 s on two (2 cores,
#: in turn); the benchmark's hour in 5-minute recordings (60,000 rows each) gains from them
LAG_THREADS_FROM_ROWS, LAG_THREADS_RECORDING_ROWS = 100_000, 30_000

#: Hz, the rate the gap finder analyses at (block means of faster recordings; :func:`gap_data`)
RATE_HZ = 25.0
#: Hz, a held rotor stream updating slower than this is fitted on its updates only (:func:`gap_data`): a
#: 10 Hz stream interpolates over 0.1 s, half the time a vehicle takes to cross the heights where a ground
#: effect changes; a controller's 25 Hz commands leave the interpolation little to miss and a motor lag to show
THIN_BELOW_HZ = 10.0


@dataclass
class GapData:
    """Samples of one or more flights for the translational fit (``K`` rows).

    Attributes
    ----------
    group : (K,) int, recording index
    t : (K,) s since each recording's start
    p : (K, 3) m, position in W
    y : (K, 3) N, measured total non-gravity force in W
    R : (K, 3, 3) body to world
    rotor_speeds : (K, N) rad/s (recorded)
    v : (K, 3) m/s in W
    d_down, d_up : (K,) m, rotor plane to the surfaces (``inf`` where no surface / no point cloud)
    mass, rotor_radius : kg, m
    names : recording names
    imu : (K,) bool, rows whose force comes from an accelerometer
    fits_bias : the model has accelerometer-bias columns (False where the bias was anchored
        against motion capture, :mod:`uavturb.sysid.nominal`, or there is no IMU)
    level : (K,) -, thrust level of each row's recording (:func:`uavturb.sysid.nominal.thrust_levels`;
        None: all 1)
    contiguous : the flights before rows were dropped (motor lag needs contiguous rows), holding only the columns
        read of them once the rows are built (the others None: :func:`_slimmed`), and
    rows : (K,) int, the indices of these rows in ``contiguous``; where rows are block means of
        consecutive samples (:func:`gap_data`'s ``rate_hz``), the indices of every member sample, and
    block_of : (M,) int, the row each member sample belongs to (None: one sample a row)
    anchored : ``{recording name: AnchoredBias}``, accelerometer biases measured against motion capture
    arm_length : m, the vehicle's arm (sizes the airframe for physical ranges; nan: unknown)
    voltage_dev : (K,) V, the battery's voltage minus its recording's mean in flight (``battery0``; None where a
        recording has none: :func:`gap_data`), and
    voltage_means : ``{recording name: V}``, those means
    voltage_noise : ``{recording name: V^2}``, the variance of each recording's voltage noise at a row
        (:func:`~uavturb.sysid.flight_data.battery_voltage_noise`; block means keep it: a bound, blocks averaging
        samples of the battery stream have less)
    rotor_quantum : rad/s, the recorded rotor speeds' resolution
        (:func:`~uavturb.numerics.stream_updates.rotor_quantum`; 0: not quantised), set by
        the finder on the rows it analyses (subsets and block means do not carry it)
    dense : where a held rotor stream thinned the rows to its updates (:attr:`FlightData.rotor_fresh`), the
        rows in flight before that (sums over many rows, such as thrust levels, average the interpolation
        errors out and use them); None otherwise, and in subsets
    """

    group: np.ndarray
    t: np.ndarray
    p: np.ndarray
    y: np.ndarray
    R: np.ndarray
    rotor_speeds: np.ndarray
    v: np.ndarray
    d_down: np.ndarray
    d_up: np.ndarray
    mass: float
    rotor_radius: float
    names: list[str]
    source: str
    imu: np.ndarray | None = None
    fits_bias: bool = True
    level: np.ndarray | None = None
    contiguous: "GapData | None" = field(default=None, repr=False)
    rows: np.ndarray | None = None
    block_of: np.ndarray | None = None
    anchored: dict = field(default_factory=dict, repr=False)
    arm_length: float = float("nan")
    voltage_dev: np.ndarray | None = None
    voltage_means: dict = field(default_factory=dict, repr=False)
    voltage_noise: dict = field(default_factory=dict, repr=False)
    rotor_quantum: float = 0.0
    _S: np.ndarray | None = field(default=None, repr=False)
    _lag_cache: dict = field(default_factory=dict, repr=False)
    _plan: list | None = field(default=None, repr=False)
    _lag_done: dict = field(default_factory=dict, repr=False)
    _groups: frozenset | None = field(default=None, repr=False)
    _zb: np.ndarray | None = field(default=None, repr=False)
    dense: "GapData | None" = field(default=None, repr=False)
    #: the roll and pitch torques' lag behind commanded rotor speeds
    #: read on the contiguous flights (None: measured or held speeds; subsets do not carry it)
    torque_lag: CommandLag | None = field(default=None, repr=False)
    #: which order of the rotor columns the roll and pitch accelerations follow, read on the contiguous flights
    #: (:mod:`uavturb.sysid.rotor_order`; None: not read, or too few rows; subsets do not carry it)
    rotor_order: RotorOrder | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def S(self) -> np.ndarray:
        """(K,) (rad/s)^2, ``sum(w_i^2)`` (computed once: the fits read it thousands of times)."""
        if self._S is None:
            self._S = sum_of_squares(self.rotor_speeds)
        return self._S

    @property
    def z_body_rows(self) -> np.ndarray:
        """(3, K) -, the body z axis in W (``R[:, :, 2]``) as three contiguous rows (computed once: every
        evaluation of a fit's thrust column reads it)."""
        if self._zb is None:
            self._zb = np.ascontiguousarray(self.R[:, :, 2].T)
        return self._zb

    @property
    def geometry(self) -> dict:
        """What surface laws that use the rotor spacing need: ``arm_length`` [m] (nan where unknown: such
        a law is then nan, and its reach the closed form's) and ``rotor_count``."""
        return {"arm_length": self.arm_length, "rotor_count": self.rotor_speeds.shape[1]}

    @property
    def thrust_level(self) -> np.ndarray:
        """(K,) -, each row's thrust level (ones where recordings share one thrust coefficient)."""
        return np.ones(len(self)) if self.level is None else self.level

    @property
    def has_imu(self) -> bool:
        """Some rows come from an accelerometer (so an accelerometer bias exists)."""
        return bool(self.imu is not None and np.any(self.imu))

    def gather(self, values: np.ndarray) -> np.ndarray:
        """Values of the contiguous flights ``(len(contiguous), ...)`` on these rows (block means where
        rows are blocks)."""
        if self.block_of is None:
            return values[self.rows]
        counts = np.bincount(self.block_of, minlength=len(self)).astype(float)
        v = values[self.rows].reshape(len(self.rows), -1)
        out = np.stack([np.bincount(self.block_of, weights=v[:, j], minlength=len(self)) for j in range(v.shape[1])],
                       axis=1) / counts[:, None]
        return out.reshape((len(self),) + values.shape[1:])

    def S_lag(self, tau: float) -> np.ndarray:
        """``sum(w_lag^2)`` with rotor speeds lagging the records by ``tau`` [s] (per recording),
        computed on the contiguous flights when these rows are a subset of them (on the recordings these rows
        hold only: a fold's search needs its training recordings')."""
        key = lag_key(tau)
        if self.contiguous is None:
            return self._lagged_sums(key, None)
        if key not in self._lag_cache:
            if self._groups is None:
                self._groups = frozenset(np.unique(self.group).tolist())
            # a search returns to values it tried: the block means are kept too
            return self._keep_lagged(key, self.gather(self.contiguous._lagged_sums(key, self._groups)))
        return self._recently_used(key)

    def _lagged_sums(self, key: float, groups: frozenset | None) -> np.ndarray:
        """(K,) the lagged sums at the cached ``tau`` ``key``, filled on the rows of the recordings ``groups``
        at least (None: all); each recording's lag is filtered once per ``key``."""
        out = self._recently_used(key) if key in self._lag_cache else self._keep_lagged(key, np.empty(len(self)))
        done = self._lag_done.setdefault(key, set())
        todo = [(g, rows, stretches) for g, rows, stretches in self._lag_plan()
                if g not in done and (groups is None or g in groups)]
        # each recording alone, so several at once where they are long (the filter's passes over whole arrays
        # release the GIL)
        rows_to_filter = sum(r.stop - r.start if isinstance(r, slice) else len(r) for _, r, _ in todo)
        threaded = rows_to_filter >= max(LAG_THREADS_FROM_ROWS, LAG_THREADS_RECORDING_ROWS * len(todo))
        for (g, rows, _), lagged in zip(todo, in_threads(
                lambda plan: sum_of_squares(lag_rotor_speeds(self.t[plan[1]], self.rotor_speeds[plan[1]], key,
                                                             plan[2])), todo, max_threads=None if threaded else 1)):
            out[rows] = lagged
            done.add(g)
        return out

    def _recently_used(self, key: float) -> np.ndarray:
        """The kept lagged sums at ``key``, moved to the end of the cache's order: the cache drops the value of tau
        used least recently (:meth:`_keep_lagged`), not the oldest kept. Every search visits the coarse grid's values
        of tau again and again between its finer ones; dropped first, they were filtered anew up to eight times
        (twelve recordings: 6933 filters of 2546 distinct ones, a tenth of the analysis)."""
        self._lag_cache[key] = self._lag_cache.pop(key)
        return self._lag_cache[key]

    def _keep_lagged(self, key: float, out: np.ndarray) -> np.ndarray:
        """Keep ``out`` as the lagged sums at ``key``, the least recently used (:meth:`_recently_used`) dropped
        beyond :data:`LAG_CACHE_BYTES` or :data:`LAG_CACHE_TAUS` values (:data:`ROWS_LAG_CACHE_BYTES`,
        :data:`ROWS_LAG_CACHE_TAUS` for rows of contiguous flights)."""
        limit = LAG_CACHE_BYTES if self.contiguous is None else ROWS_LAG_CACHE_BYTES
        taus = LAG_CACHE_TAUS if self.contiguous is None else ROWS_LAG_CACHE_TAUS
        while (len(self._lag_cache) * out.nbytes > limit or len(self._lag_cache) >= taus) and self._lag_cache:
            old = next(iter(self._lag_cache))
            self._lag_cache.pop(old)
            self._lag_done.pop(old, None)
        self._lag_cache[key] = out
        return out

    def _lag_plan(self) -> list:
        """``[(recording, rows, stretches)]``: each recording's rows (a slice where they are consecutive, as
        :func:`gap_data` stacks them) and their :func:`~uavturb.physics.effects.lag_stretches`; found once, as
        they depend on the times only and :meth:`S_lag` runs at many ``tau``."""
        if self._plan is None:
            g = self.group
            if len(g) and np.all(g[1:] >= g[:-1]):
                edges = np.r_[0, np.flatnonzero(np.diff(g)) + 1, len(g)]
                parts = [(int(g[a]), slice(int(a), int(b))) for a, b in zip(edges[:-1], edges[1:])]
            else:
                parts = [(int(k), np.flatnonzero(g == k)) for k in np.unique(g)]
            self._plan = [(k, rows, lag_stretches(self.t[rows])) for k, rows in parts]
        return self._plan

    def with_speed_offset(self, delta: float, w_hover: float | None = None) -> "GapData":
        """These rows with every turning rotor's recorded speed ``w`` [rad/s] moved by ``delta`` [rad/s]: to ``w +
        delta``, or where the hover speed ``w_hover`` [rad/s] is given to ``(w + delta) w_hover / (w_hover + delta)``
        (:func:`~uavturb.sysid.nominal.moved_speeds`); on the contiguous flights too,
        so the motor lag filters the moved speeds. Stopped rotors (0) stay stopped. Nothing is shared with ``self``
        that the move changes (:mod:`uavturb.sysid.nominal`, **Thrust map**)."""
        contiguous = None if self.contiguous is None else self.contiguous.with_speed_offset(delta, w_hover)
        return replace(self, rotor_speeds=moved_speeds(self.rotor_speeds, delta, w_hover), contiguous=contiguous,
                       dense=None,
                       _S=None, _lag_cache={}, _lag_done={}, _groups=None)

    def with_levels(self, level: np.ndarray) -> "GapData":
        """These rows with each recording's thrust level ``level`` (G,) [-] (on the contiguous flights too, where
        the motor lag reads them)."""
        level = np.asarray(level, float)
        contiguous = None if self.contiguous is None else replace(self.contiguous, level=level[self.contiguous.group])
        return replace(self, level=level[self.group], contiguous=contiguous, _lag_cache={}, _lag_done={})

    def subset(self, mask: np.ndarray) -> "GapData":
        """The rows where ``mask`` holds; they keep a reference to the contiguous flights."""
        block_of = None
        if self.rows is None:
            rows = np.flatnonzero(mask)
        elif self.block_of is None:
            rows = self.rows[mask]
        else:
            members = mask[self.block_of]
            rows, block_of = self.rows[members], (np.cumsum(mask) - 1)[self.block_of[members]]
        return GapData(self.group[mask], self.t[mask], self.p[mask], self.y[mask], self.R[mask],
                       self.rotor_speeds[mask], self.v[mask], self.d_down[mask], self.d_up[mask], self.mass,
                       self.rotor_radius, self.names, self.source,
                       None if self.imu is None else self.imu[mask], self.fits_bias,
                       None if self.level is None else self.level[mask],
                       self if self.contiguous is None else self.contiguous, rows, block_of, self.anchored,
                       self.arm_length, None if self.voltage_dev is None else self.voltage_dev[mask],
                       self.voltage_means, self.voltage_noise)


def _smooth_height(t: np.ndarray, z: np.ndarray, window_s: float) -> np.ndarray:
    """``z`` [m] through a quadratic Savitzky-Golay filter of ``window_s`` [s]."""
    dt = float(np.median(np.diff(t)))
    n = max(5, int(round(window_s / dt)) | 1)
    return savgol_filter(z, n, 2) if len(z) > n else z


def _in_flight(fd: FlightData, mass: float, k_T_guess: float | None, min_thrust_ratio: float,
               exclude: np.ndarray | None) -> np.ndarray:
    """(K,) bool: rows away from the derivative filter's edges whose rotors carry more than
    ``min_thrust_ratio`` of the weight, outside ``exclude`` (ground contact) and a stream's dropouts."""
    S = np.sum(fd.rotor_speeds**2, axis=1)
    keep = np.ones(len(fd), bool)
    keep[: fd.window] = keep[-fd.window:] = False
    thr = (k_T_guess * S) if k_T_guess else (S / np.median(S) * mass * GRAVITY)
    keep &= thr > min_thrust_ratio * mass * GRAVITY
    if exclude is not None:
        keep &= ~exclude
    if fd.covered is not None:  # a stream's dropouts are not interpolated across
        keep &= fd.covered
    return keep


def gap_data(flights: list[FlightData], mass: float, rotor_radius: float, *, source: str = "auto",
             min_thrust_ratio: float = 0.3, k_T_guess: float | None = None,
             height_window_s: float = 0.3, exclude: list[np.ndarray] | None = None,
             anchor_bias: bool = True, arm_length: float = float("nan"), rate_hz: float | None = RATE_HZ,
             release: bool = False, masses: Sequence[float] | None = None, sim_forces: bool = True) -> GapData:
    """Stack flights into :class:`GapData`, keeping samples in flight (not resting on a surface).

    ``mass`` [kg] is the vehicle's (ranges, the accelerometer bias's columns); ``masses`` [kg], one per flight where
    their vehicle.yaml files differ by a battery's few percent, weigh each flight's own forces.

    Rows at the derivative filter's edges, rows whose rotors carry less than
    ``min_thrust_ratio`` of the weight and the rows of ``exclude`` (one ``(K,)`` mask per flight:
    ground contact) are left out. Heights over and under surfaces use the rotor plane's height
    smoothed over ``height_window_s`` [s]. Motor lag needs contiguous rows: the lag filter runs on
    each flight before rows are dropped (:attr:`GapData.contiguous`).

    With ``rate_hz`` (default :data:`RATE_HZ`), faster recordings are analysed as block means of
    consecutive samples at about that rate (:func:`block_means`): the effects of the vocabulary change
    over tenths of seconds, and the fits, repeated hundreds of times in a selection, cost in proportion
    to the rows. ``None`` keeps every sample.

    With ``anchor_bias`` (default), the accelerometer bias of a flight with an IMU is measured
    against its motion capture (:func:`uavturb.sysid.accelerometer.anchored_bias`) and taken off the
    accelerometer, so the model fits no bias that could trade with the thrust coefficient; the
    biases are in :attr:`GapData.anchored`.

    With ``release``, each flight is taken out of ``flights`` (its place set to None) as it is read, so that
    what the rows do not keep of it (attitudes, rates, derivatives, the IMU) is freed before the columns are
    joined: building a flight-hour in twelve recordings peaked 92 MB lower (the whole analysis 48 MB). The caller's
    list is left holding None.

    The contiguous flights keep only what is read of them once the rows are built (:func:`_slimmed`): the motor
    lag's times, recordings and rotor speeds, and with ``sim_forces`` (default) what the simulator's own effects are
    computed on at full rate (attitudes, velocities, heights). ``sim_forces=False`` where the simulator models no
    effect.
    """
    parts, anchored, names, voltage_means, voltage_noise = [], {}, [f.name for f in flights], {}, {}
    for g, fd in enumerate(flights):
        if release:
            flights[g] = None
        use_imu = fd.acc is not None and source in ("auto", "imu")
        R = quat.to_rotation_matrix(fd.q)
        m = mass if masses is None else float(masses[g])
        keep = _in_flight(fd, m, k_T_guess, min_thrust_ratio, None if exclude is None else exclude[g])
        # a held rotor stream (ESC telemetry at 3 Hz): between its updates the speeds are interpolated,
        # off by the thrust changes of a third of a second; only the rows of its updates are measured
        slow = fd.rotor_fresh is not None and fd.rotor_fresh.sum() < THIN_BELOW_HZ * np.ptp(fd.t)
        fresh = keep & fd.rotor_fresh if slow else keep
        if use_imu:
            acc = fd.acc
            if anchor_bias:
                anchored[fd.name] = anchored_bias(fd.t, R, fd.acc, fd.dv, keep)
                acc = fd.acc - anchored[fd.name].b
            y = m * np.einsum("kij,kj->ki", R, acc)
        else:
            y = m * (fd.dv + np.array([0.0, 0.0, GRAVITY]))
        inf = np.full(len(fd), np.inf)
        # heights with the position noise taken out: MoCap noise is white, the body's height
        # changes slowly, and the surface laws are steep near a surface (1 mm at 6 cm over the
        # floor is 0.26 N of ground effect at mu = 2). The surface heights under and over the
        # body (steps at table edges) are kept: only the body's own height is smoothed.
        dz = _smooth_height(fd.t, fd.p[:, 2], height_window_s) - fd.p[:, 2]
        d_down = np.where(np.isfinite(fd.d_down), fd.d_down + dz, np.inf) if fd.d_down is not None else inf
        d_up = np.where(np.isfinite(fd.d_up), fd.d_up - dz, np.inf) if fd.d_up is not None else inf
        parts.append(dict(group=np.full(len(fd), g), t=fd.t, p=fd.p, y=y, R=R, rotor_speeds=fd.rotor_speeds, v=fd.v,
                          d_down=d_down, d_up=d_up, keep=keep, fresh=fresh, imu=np.full(len(fd), use_imu),
                          src="imu" if use_imu else "mocap",
                          volts=_voltage_deviation(fd, keep, voltage_means, voltage_noise)))
    sources = "+".join(sorted({p.pop("src") for p in parts}))
    volts = [p.pop("volts") for p in parts]
    voltage_dev = None if any(v is None for v in volts) else np.concatenate(volts)
    # one column at a time, each flight's own arrays let go as they are joined (a single flight's are used as
    # they are): at 200 Hz the columns take ~230 bytes a row, and the flights' aligned streams are held besides
    cat = {k: parts[0].pop(k) if len(parts) == 1 else np.concatenate([p.pop(k) for p in parts])
           for k in list(parts[0])}
    keep, fresh = cat.pop("keep"), cat.pop("fresh")
    full = GapData(**cat, mass=mass, rotor_radius=rotor_radius, names=names,
                   source=sources,
                   fits_bias=bool(np.any(cat["imu"])) and not anchor_bias, arm_length=arm_length,
                   voltage_dev=voltage_dev, voltage_means=voltage_means if voltage_dev is not None else {},
                   voltage_noise=voltage_noise if voltage_dev is not None else {})
    full.anchored = anchored
    n = block_size(full, rate_hz)
    if not fresh.any():  # nothing in flight: the caller says so in one line
        return full.subset(fresh)
    dense = full.subset(keep) if n <= 1 else block_means(full, keep, n)
    data = dense
    if not np.array_equal(fresh, keep):
        data = full.subset(fresh) if n <= 1 else block_means(full, fresh, n)
        data.dense = dense
    _slimmed(full, sim_forces)
    return data


def _slimmed(full: GapData, sim_forces: bool) -> None:
    """Let go of the columns of the contiguous flights ``full`` that nothing reads once the rows are built (their
    own copies, block means or subsets, are made): the positions, forces, IMU flags and voltages always; the
    attitudes, velocities and heights unless ``sim_forces`` (:func:`uavturb.gap.finder`'s simulator offset reads
    them at full rate). The motor lag reads the times, recordings and rotor speeds (:meth:`GapData.S_lag`)."""
    full.p = full.y = full.imu = full.voltage_dev = None
    if not sim_forces:
        full.R = full.v = full.d_down = full.d_up = None


#: share of a recording's rows in flight that its battery stream must cover for the voltage to be read
VOLTAGE_COVER = 0.9


def _voltage_deviation(fd: FlightData, keep: np.ndarray, means: dict, noise: dict) -> np.ndarray | None:
    """(K,) V, the flight's battery voltage minus its mean over the rows in flight (``keep``), 0 where the stream
    does not reach; its mean goes into ``means`` under the flight's name, and its noise's variance at a row [V^2]
    (``FlightData.voltage_noise_v2``) into ``noise``. None without a battery stream, or one that covers under
    :data:`VOLTAGE_COVER` of the rows in flight (a law in the voltage cannot be fitted there)."""
    if fd.voltage is None or not keep.any():
        return None
    known = np.isfinite(fd.voltage)
    if known[keep].mean() < VOLTAGE_COVER:
        return None
    means[fd.name] = float(np.mean(fd.voltage[keep & known]))
    noise[fd.name] = float(fd.voltage_noise_v2 or 0.0)
    return np.where(known, fd.voltage - means[fd.name], 0.0)


def block_size(data: GapData, rate_hz: float | None) -> int:
    """Samples a row averages to bring the data's rate down to about ``rate_hz`` (1: none)."""
    if not rate_hz or len(data) < 2:
        return 1
    dt = float(np.median(np.diff(data.t)))
    return max(1, int(round(1.0 / (dt * rate_hz)))) if dt > 0 else 1


def block_means(full: GapData, keep: np.ndarray, n: int) -> GapData:
    """Rows that are means of ``n`` consecutive kept samples of one recording (no dropped row between
    them): ``y``, positions, velocities, attitudes' columns and heights averaged, rotor speeds as the
    root mean square (so ``sum(w^2)`` is the mean of the samples'), times as the mean. The model is
    linear in its regressors for given nonlinear parameters, and every regressor changes slowly
    against ``n`` samples (a block is 40 ms at the default 25 Hz), so the fit on block means is the
    fit on the samples with the white noise averaged; motor lag is filtered on the contiguous samples
    and averaged over each block (:meth:`GapData.S_lag`)."""
    idx = np.flatnonzero(keep)
    starts = np.r_[True, (np.diff(idx) != 1) | (np.diff(full.group[idx]) != 0)]
    run = np.cumsum(starts) - 1
    pos = np.arange(len(idx)) - np.flatnonzero(starts)[run]
    block_key = run * (len(idx) + 1) + pos // n
    _, block_of = np.unique(block_key, return_inverse=True)
    K = int(block_of.max()) + 1
    counts = np.bincount(block_of, minlength=K).astype(float)

    def mean(x: np.ndarray, squared: bool = False) -> np.ndarray:
        # one column at a time: the kept samples of a flight-hour's attitudes alone are 52 MB
        v = np.asarray(x, float).reshape(len(x), -1)
        out = np.empty((K, v.shape[1]))
        for j in range(v.shape[1]):
            column = v[idx, j]
            out[:, j] = np.bincount(block_of, weights=column**2 if squared else column, minlength=K)
        return (out / counts[:, None]).reshape((K,) + np.shape(x)[1:])

    with np.errstate(invalid="ignore"):
        d_down, d_up = mean(full.d_down), mean(full.d_up)
    group = full.group[idx][np.unique(block_of, return_index=True)[1]]
    rms_speeds = np.sqrt(mean(full.rotor_speeds, squared=True))
    data = GapData(group, mean(full.t), mean(full.p), mean(full.y), mean(full.R),
                   rms_speeds, mean(full.v), np.where(np.isnan(d_down), np.inf, d_down),
                   np.where(np.isnan(d_up), np.inf, d_up), full.mass, full.rotor_radius, full.names, full.source,
                   None if full.imu is None else mean(full.imu) > 0.5, full.fits_bias, None, full, idx,
                   block_of, full.anchored, full.arm_length,
                   None if full.voltage_dev is None else mean(full.voltage_dev), full.voltage_means,
                   full.voltage_noise)
    return data


def surface_reach_m(data: GapData) -> float:
    """m, the farthest any one-parameter surface law of the registry reaches at the top of its range (laws
    with several parameters have no top of their range): beyond it a row is free of surfaces."""
    return max(e.surface_reach(data.rotor_radius, **data.geometry) for e in EFFECTS.values()
               if e.surface and len(e.params) == 1)


def apply_thrust_levels(data: GapData) -> ThrustLevels:
    """Measure each recording's thrust level far from surfaces, or at matched heights where the flights
    stay within a surface's reach (:func:`uavturb.sysid.nominal.thrust_levels`), and, where they differ,
    give each row its recording's level (``data.level``)."""
    reach = surface_reach_m(data)
    rows = data if data.dense is None else data.dense  # sums: every row in flight counts
    far = (rows.d_down > reach) & (rows.d_up > reach)
    y_thrust = np.einsum("ki,ki->k", rows.y, rows.R[:, :, 2])
    # matched heights: binned by the height over the floor, out of the ceiling's reach
    levels = thrust_levels(rows.group, rows.t, y_thrust, rows.S, far, rows.names,
                           height=rows.d_down, matched=rows.d_up > reach, voltage_dev=rows.voltage_dev)
    if levels.differ:
        data.level = levels.level[data.group]
        if data.contiguous is not None:
            data.contiguous.level = levels.level[data.contiguous.group]
    return levels


def surface_law_extra(data: GapData, name: str, value: float) -> np.ndarray:
    """(K,) -, the extra thrust per unit thrust, ``T_IGE/T_OGE - 1``, of the surface law ``name`` of the
    registry at its searched parameter's ``value``, at each row's height to its surface (its ``ratio``; 0 where
    the law does not hold, under its pole, as the paper clips the ground effect). A law with an ``amplitude``
    gives its shape: the extra thrust at amplitude 1, at and under the surface its value there (as its force)."""
    spec = EFFECTS[name]
    d = data.d_down if spec.surface == "d_down" else data.d_up
    if spec.amplitude is not None:
        d = np.maximum(d, 1e-12)
        values = tuple(1.0 if p == spec.amplitude else value for p in spec.params)
        ratio = spec.ratio_at(d, values, data.rotor_radius, **data.geometry)
    else:
        ratio = spec.ratio(d, value, data.rotor_radius, **data.geometry)
    return np.where(np.isfinite(ratio), ratio - 1.0, 0.0)


def sum_of_squares(w: np.ndarray) -> np.ndarray:
    """(K,) ``sum(w_i^2)`` over the columns of ``w`` (K, N): ``np.sum(w**2, axis=1)`` to the bit, 4 times as
    fast for fewer than 8 columns (numpy sums so few in order, one row at a time; here a column at a time)."""
    if w.ndim != 2 or w.shape[1] >= 8 or w.shape[1] == 0:
        return np.sum(w**2, axis=1)
    out = np.square(w[:, 0])
    for j in range(1, w.shape[1]):
        out += np.square(w[:, j])
    return out


def lag_key(tau: float) -> float:
    """s, the motor lag's ``tau`` at which :meth:`GapData.S_lag` filters: three significant digits (0.5 % at
    most, far under its honest error), so that the searches of every fold and candidate land on the same
    few values and share their lagged sums."""
    return float(f"{float(tau):.3g}")


def applied_value(effect: str, value: float) -> float:
    """The value of a nonlinear effect's parameter at which :func:`design` computes its columns (the motor
    lag's cached grid, :func:`lag_key`; every other parameter as given)."""
    return lag_key(value) if effect == "motor_lag" else float(value)


def difference_points(effect: str, value: float) -> tuple[float, float]:
    """(upper, lower) values of a nonlinear effect's parameter for a central difference of the design's
    columns around ``value``, at the values they are really computed at (:func:`applied_value`): 0.1 %
    either side, or 2 % where that falls within one step of a cached grid (the motor lag's)."""
    if value <= 0.0:
        return 1e-6, 0.0
    hi, lo = applied_value(effect, value * (1 + 1e-3)), applied_value(effect, value * (1 - 1e-3))
    if hi == lo:
        hi, lo = applied_value(effect, value * 1.02), applied_value(effect, value * 0.98)
    return hi, lo


def lagged_S(data: GapData, tau: float) -> np.ndarray:
    """``sum(w_lag^2)`` on the rows of ``data`` (lag run on the contiguous flights)."""
    return data.S_lag(tau)


def design(data: GapData, effects: set[str], nonlinear: dict[str, float]) -> tuple[np.ndarray, list[str]]:
    """Regressors ``A (3K, P)`` (rows: x of all samples, then y, then z) and the coefficient names.

    Parameters
    ----------
    data : samples
    effects : the effects in the model (names of ``effects.md``)
    nonlinear : values of ``mu``, ``kappa``, ``tau``, ``lam`` for the nonlinear effects in ``effects``
    """
    Ad, dnames = dependent_columns(data, effects, nonlinear)
    Af, fnames = fixed_columns(data, effects)
    # order: k_T, biases, the thrust factors (k_T*s, k_T*k_V) and the amplitudes (k_T*A), then the linear effects
    nb = bias_count(data)
    return (np.hstack([Ad[:, :1], Af[:, :nb], Ad[:, 1:], Af[:, nb:]]),
            dnames[:1] + fnames[:nb] + dnames[1:] + fnames[nb:])


def dependent_columns(data: GapData, effects: set[str], nonlinear: dict[str, float]) -> tuple[np.ndarray, list[str]]:
    """The columns of :func:`design` that depend on ``mu``, ``kappa``, ``tau``, ``lam``: thrust with the
    surface effects (``k_T``), each law that scales the thrust coefficient (:data:`THRUST_FACTOR`: ``k_T*s``,
    ``k_T*k_V``), and the shape of each surface law with an amplitude (``k_T*A``). ``(3K, 1 + ...)``."""
    return thrust_columns(data, effects, effective_S(data, effects, nonlinear), surface_extra(data, effects, nonlinear),
                          amplitude_shapes(data, effects, nonlinear))


def effective_S(data: GapData, effects: set[str], nonlinear: dict[str, float]) -> np.ndarray:
    """(K,) (rad/s)^2, ``sum(w^2)`` the thrust sees: lagged by ``tau`` with ``motor_lag``, times each row's
    thrust level."""
    S = lagged_S(data, nonlinear["tau"]) if "motor_lag" in effects else data.S
    return S * data.thrust_level


def surface_extra(data: GapData, effects: set[str], nonlinear: dict[str, float]) -> np.ndarray:
    """(K,) -, the extra thrust per unit thrust of every surface law in ``effects`` without an amplitude, at
    its parameter."""
    surf = np.zeros(len(data))
    for name in sorted(effects):
        if EFFECTS[name].surface is not None and name not in AMPLITUDE:
            surf += surface_law_extra(data, name, nonlinear[EFFECTS[name].searched_param])
    return surf


def amplitude_shapes(data: GapData, effects: set[str], nonlinear: dict[str, float]) -> list[np.ndarray]:
    """(K,) -, the shape of each surface law in ``effects`` with an amplitude (:data:`AMPLITUDE`, in name order)
    at its searched parameter: its extra thrust per unit thrust at amplitude 1."""
    return [surface_law_extra(data, name, nonlinear[EFFECTS[name].searched_param])
            for name in sorted(effects) if name in AMPLITUDE]


def amplitude_names(effects: set[str] | frozenset[str]) -> list[str]:
    """The coefficients of :func:`amplitude_shapes`' columns (``k_T*A``), in their order."""
    return [AMPLITUDE[name] for name in sorted(effects) if name in AMPLITUDE]


def thrust_factor_names(effects: set[str] | frozenset[str]) -> list[str]:
    """The coefficients of the laws in ``effects`` that scale the thrust coefficient (:data:`THRUST_FACTOR`), in
    name order."""
    return [THRUST_FACTOR[name] for name in sorted(effects) if name in THRUST_FACTOR]


def thrust_columns(data: GapData, effects: set[str], S: np.ndarray, surf: np.ndarray,
                   shapes: list[np.ndarray] = (), out: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """:func:`dependent_columns` from the effective ``S`` (K,), the surface laws' ``surf`` (K,) and the shapes
    of the laws with an amplitude (:func:`amplitude_shapes`).

    The thrust column is ``S R e_z`` with ``S surf`` added along ``z`` of W (``k_T``); each law that scales the
    thrust coefficient adds ``x S R e_z`` with its factor ``x`` (``EffectSpec.thrust_factor``: the battery's
    ``-t``, ``k_T*s``; its voltage's ``V - V_mean``, ``k_T*k_V``); each amplitude's ``S shape`` along ``z`` of W
    (``k_T*A``); written straight into the ``(3K, P)`` array, each axis of W from the body z axis's contiguous row
    (:attr:`GapData.z_body_rows`): the columns are the fits' innermost work. ``out``: a ``(3K, P)`` array (a view
    of a wider one allowed) that the columns are written into and returned as, in place of a new one."""
    factors = [name for name in sorted(effects) if name in THRUST_FACTOR]
    amplitudes = amplitude_names(effects)
    if len(shapes) != len(amplitudes):
        raise ValueError(f"{len(shapes)} shapes given for the amplitudes {amplitudes}")
    names = ["k_T"] + thrust_factor_names(effects) + amplitudes
    K, zb = len(S), data.z_body_rows
    if out is not None and out.shape != (3 * K, len(names)):
        raise ValueError(f"out has shape {out.shape}, the columns {(3 * K, len(names))}")
    D = np.empty((3 * K, len(names))) if out is None else out
    for j in range(3):
        np.multiply(S, zb[j], out=D[j * K:(j + 1) * K, 0])
    D[2 * K:, 0] += S * surf
    x = effect_inputs(data) if factors else None
    for c, name in enumerate(factors, start=1):
        xs = EFFECTS[name].thrust_factor(x) * S
        for j in range(3):
            np.multiply(xs, zb[j], out=D[j * K:(j + 1) * K, c])
    for c, shape in enumerate(shapes, start=1 + len(factors)):
        D[:2 * K, c] = 0.0
        np.multiply(S, shape, out=D[2 * K:, c])
    return D, names


def fixed_columns(data: GapData, effects: set[str]) -> tuple[np.ndarray, list[str]]:
    """The columns of :func:`design` that do not depend on the nonlinear parameters: the
    accelerometer bias (body frame; rows with an IMU only, none without any IMU) and the linear
    effects, each parameter's column its law's force at that parameter = 1 (the registry's ``force``:
    a linear law is one registry entry, nothing here). ``(3K, P_f)``."""
    K = len(data)
    R = data.R
    cols, names = [], []
    if data.fits_bias:
        on = np.ones(K) if data.imu is None else data.imu.astype(float)
        for j, ax in enumerate("xyz"):
            cols.append(data.mass * R[:, :, j] * on[:, None])
            names.append(f"b_{ax}")
    x = None
    for name in sorted(effects, key=list(EFFECTS).index):
        spec = EFFECTS[name]
        if not spec.linear or spec.along_thrust:
            continue  # thrust-scaled laws are dependent columns (their coefficient carries k_T)
        if x is None:
            x = effect_inputs(data)
        for p in spec.params:  # a linear law's column per parameter: its force at that parameter = 1
            cols.append(spec.force(x, **{q: float(q == p) for q in spec.params}))
            names.append(p)
    if not cols:
        return np.zeros((3 * K, 0)), names
    return np.stack([c.T.reshape(-1) for c in cols], axis=1), names


def effect_inputs(data: GapData) -> EffectInputs:
    """What the registry's laws need, on the rows of ``data`` (``k_T`` = 1: thrust in units of ``k_T``)."""
    return EffectInputs(q=None, v=data.v, rotor_speeds=data.rotor_speeds, k_T=1.0, rotor_radius=data.rotor_radius,
                        d_down=data.d_down, d_up=data.d_up, t=data.t, R=data.R, arm_length=data.arm_length,
                        voltage_dev=data.voltage_dev)


def bias_count(data: GapData) -> int:
    """Number of accelerometer-bias columns in :func:`design` (3, or 0 without an IMU)."""
    return 3 if data.fits_bias else 0


def stack_target(y: np.ndarray) -> np.ndarray:
    """``(K, 3)`` → ``(3K,)`` in the row order of :func:`design`."""
    return y.T.reshape(-1)


def unstack(r: np.ndarray) -> np.ndarray:
    """``(3K,)`` → ``(K, 3)``."""
    return r.reshape(3, -1).T


#: effects whose force acts along the thrust (they scale or lag the thrust): a thrust regressor
#: corrupted by rounded rotor speeds can be mistaken for them (from the registry)
THRUST_AXIS = frozenset(n for n, e in EFFECTS.items() if e.along_thrust)


def rounding_floor(data: GapData, k_T: float, quantum: float) -> float:
    """Mean variance [N^2] of the thrust error from rotor speeds rounded to ``quantum`` [rad/s]:
    ``T = k_T sum(w_i^2)`` with ``w_i`` off by ``e_i``, uniform in ``+-quantum/2``, is off by
    ``2 k_T sum(w_i e_i)`` (variance ``(2 k_T)^2 sum(w_i^2) quantum^2 / 12``). In a still hover the
    rounding stays the same for seconds, so this error does not average out: a law along the
    thrust axis that reduces the held-out squared error by less than this may be fitting it."""
    if quantum <= 0:
        return 0.0
    return float(np.mean((2.0 * k_T) ** 2 * data.S * quantum**2 / 12.0))
