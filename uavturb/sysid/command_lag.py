"""How far rotors lag the commanded speeds a flight controller records, read on the rotor torques.

Most vehicles record the speeds they command (``vehicle.yaml``'s ``rotor_speed_source``: commanded), and their
motors follow them with a first-order lag (``effects.md``'s ``motor_lag``: RotorS's 12.5-25 ms, Neural-Lander's
45 ms; on Neural-Swarm's Crazyflies the thrust lags 56-77 ms, the torques 10-23 ms). Torques computed from the
commands then lead the angular acceleration they cause, and a regression of one on the other reads a smaller gain:
the inertia ``l k_T / gain`` comes out high (a hexarotor's commands 30 ms ahead of its rotors: ``J_x``, ``J_y``
3-4 % high at 2-3 stated errors; 60 ms ahead: 10-13 % at 3.4-3.8).

:func:`command_lag` reads the lag ``tau`` at which the roll and pitch torques of the lagged commands line up with the
angular acceleration they cause: the time shift at which the two correlate best (Pearson's r of ``u_1(t - s)`` with
``w_dot_x(t)`` and of ``u_2(t - s)`` with ``w_dot_y(t)``, averaged; the causes filtered as the derivative is, as
:mod:`uavturb.sysid.identification` fits them) falls to zero. A shift's peak is what is read, not the least squares
of the torques on lagged commands: a lag smooths noise out of the commands, and that fit read 45 ms on noisy commands
with no lag at all (the inertia then 13 % high), where the peak, which noise lowers at every shift alike, stays at
zero. Nor the shift of the commands as recorded: a first-order lag delays a swing by ``atan(omega tau) / omega``,
less than ``tau`` for fast swings (the simulator's 30 ms motors read 32.5 so; the lagged commands' peak reaches zero at
30.4). On a lattice of ``tau`` the peak's shift is found for all the rows and without each of :data:`LAG_BLOCKS`
contiguous blocks in turn; where it crosses zero (linearly between lattice values) is the lag, the jackknife of the
blocks' values its error, with half a sample step in quadrature (a command held over a step acts from its stamp to
the next); a lag under :data:`LAG_DECISIVE_Z` errors is not applied. Torques that correlate with the angular
acceleration under ``io.consistency``'s ``TORQUE_CLOCK_MIN_CORRELATION`` at every lag tried give no reading.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from uavturb.io.consistency import TORQUE_CLOCK_MIN_CORRELATION
from uavturb.numerics.blocks import contiguous_blocks, jackknife_se
from uavturb.physics.effects import lag_rotor_speeds, lag_stretches
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.flight_data import FlightData

#: s, the largest lag searched (beyond every motor in ``effects.md``'s magnitudes and Neural-Swarm's Crazyflies), and
#: s, the lattice of lags' step; s, the shifts tried either side of zero for the peak, and their step
COMMAND_LAG_MAX_S, TAU_STEP_S = 0.2, 0.005
SHIFT_HALF_S, SHIFT_STEP_S = 0.02, 0.0025


#: contiguous blocks of each flight left out in turn for the lag's jackknife error; a lag applied stands this many
#: standard errors from zero
LAG_BLOCKS, LAG_DECISIVE_Z = 5, 2.0
#: rows the reading uses at most, shared among the flights, each's from the middle of its rows (17 shifts of 20,000
#: rows' two torques are 5 MB), and s, the rows before them its lag filter runs over to settle (five of the longest
#: lag searched)
LAG_ROWS, LAG_WARM_UP_S = 20_000, 1.0


@dataclass(frozen=True)
class CommandLag:
    """A reading of the rotors' lag behind the commanded speeds.

    Attributes
    ----------
    tau_s : s, the lag at which the lagged commands' torques correlate best with the angular acceleration unshifted
    stderr_s : s, its standard error: the jackknife over :data:`LAG_BLOCKS` blocks and half a sample step in
        quadrature (``inf`` where it cannot be formed)
    rows : rows the reading used
    correlation, correlation_at_zero : the torques' mean correlation with the angular acceleration, unshifted, with
        the commands lagged by ``tau_s`` and as recorded
    """

    tau_s: float
    stderr_s: float
    rows: int
    correlation: float
    correlation_at_zero: float

    @property
    def decisive(self) -> bool:
        """Whether the lag stands :data:`LAG_DECISIVE_Z` standard errors from zero (then it is applied)."""
        return bool(np.isfinite(self.stderr_s) and self.tau_s >= LAG_DECISIVE_Z * self.stderr_s and self.tau_s > 0)

    @property
    def ends(self) -> tuple[float, float] | None:
        """s, the lags one standard error either side (the lower clipped at 0), whose change the constants'
        errors carry; None where the error is not finite."""
        if not np.isfinite(self.stderr_s):
            return None
        return max(0.0, self.tau_s - self.stderr_s), self.tau_s + self.stderr_s

    def to_dict(self) -> dict[str, Any]:
        return {"tau_s": self.tau_s, "stderr_s": self.stderr_s, "rows": self.rows, "decisive": self.decisive,
                "correlation": self.correlation, "correlation_at_zero": self.correlation_at_zero}


def lagged(fds: Sequence[FlightData], tau: float) -> list[FlightData]:
    """The flights with their rotor speeds lagged by ``tau`` [s] (``effects.md``'s ``motor_lag``); as they are at 0."""
    if tau <= 0.0:
        return list(fds)
    return [replace(fd, rotor_speeds=lag_rotor_speeds(fd.t, fd.rotor_speeds, tau)) for fd in fds]


def command_lag(fds: Sequence[FlightData], masks: Sequence[np.ndarray], vehicle: Vehicle) -> CommandLag | None:
    """The rotors' lag behind the commanded speeds of ``fds`` read on their rows ``masks`` (module docstring); None
    with too few rows, or where the torques do not vary."""
    M = vehicle.mixer()
    per = max(LAG_ROWS // max(len(fds), 1), 10)
    parts = []
    for fd, m in zip(fds, masks):
        if m.sum() < 10:
            continue
        fd, m = _window(fd, m, per)
        idx = np.flatnonzero(m)
        parts.append((fd, idx, fd.dw[idx, :2], contiguous_blocks(fd.t[idx], LAG_BLOCKS), lag_stretches(fd.t)))
    rows = sum(len(p[1]) for p in parts)
    if rows < 50:
        return None
    shifts = np.arange(-SHIFT_HALF_S, SHIFT_HALF_S + SHIFT_STEP_S / 2, SHIFT_STEP_S)
    taus = np.arange(0.0, COMMAND_LAG_MAX_S + TAU_STEP_S / 2, TAU_STEP_S)
    at_zero = int(np.argmin(np.abs(shifts)))

    # each part's rows as one-hot block columns (rows, LAG_BLOCKS): a block's sums are products with them
    onehot = [(block[:, None] == np.arange(LAG_BLOCKS)).astype(float) for _, _, _, block, _ in parts]
    # the times each part's torques are read at, every shift's in one array (shifts * rows,)
    query = [(fd.t[idx][None, :] - shifts[:, None]).ravel() for fd, idx, _, _, _ in parts]

    def block_sums(tau: float) -> np.ndarray:
        """(LAG_BLOCKS, 2 axes, 5, shifts): per block, the sums of x, y, xy, xx, yy of the torques' rotor columns
        shifted (x) and the angular acceleration (y): each a product with the blocks' one-hot columns, and one
        interpolation for every shift (a loop over blocks and shifts had made the calls cost more than the
        arithmetic: twelve one-minute walks' reading took 0.30 s, now 0.21 s)."""
        out = np.zeros((LAG_BLOCKS, 2, 5, len(shifts)))
        for (fd, idx, dw, _, stretches), B, at in zip(parts, onehot, query):
            speeds = fd.rotor_speeds if tau <= 0 else lag_rotor_speeds(fd.t, fd.rotor_speeds, tau, stretches)
            u = fd.matched((speeds**2) @ M[1:3].T)  # the roll and pitch torques' rotor columns
            for a in (0, 1):
                x = np.interp(at, fd.t, u[:, a]).reshape(len(shifts), len(idx))  # (shifts, rows)
                y = dw[:, a]
                out[:, a, 0] += (x @ B).T
                out[:, a, 1] += (y @ B)[:, None]
                out[:, a, 2] += ((x * y) @ B).T
                out[:, a, 3] += ((x * x) @ B).T
                out[:, a, 4] += ((y * y) @ B)[:, None]
        return out

    def correlation(sums: np.ndarray, n: float) -> np.ndarray:
        """(shifts,) the mean over the two axes of Pearson's r from ``sums`` (2, 5, shifts) of ``n`` rows."""
        sx, sy, sxy, sxx, syy = np.moveaxis(sums, 1, 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = (sxy - sx * sy / n) / np.sqrt((sxx - sx * sx / n) * (syy - sy * sy / n))
        return r.mean(axis=0)

    counts = np.zeros(LAG_BLOCKS)
    for _, _, _, block, _ in parts:
        counts += np.bincount(block, minlength=LAG_BLOCKS)[:LAG_BLOCKS]
    peaks = np.full((LAG_BLOCKS + 1, len(taus)), np.nan)  # row 0: every row; row 1 + b: without block b
    corr_at_zero = np.full(len(taus), np.nan)
    for j, tau in enumerate(taus):
        sums = block_sums(float(tau))
        whole = correlation(sums.sum(axis=0), counts.sum())
        corr_at_zero[j] = whole[at_zero]
        peaks[0, j] = _peak(shifts, whole)
        for b in range(LAG_BLOCKS):
            peaks[1 + b, j] = _peak(shifts, correlation(sums.sum(axis=0) - sums[b], counts.sum() - counts[b]))
        if np.all(peaks[:, j] <= 0):
            break  # every reading has crossed zero: larger lags move the peak further below it
    if not np.isfinite(peaks[0, 0]):
        return None
    tau = _crossing(taus, peaks[0])
    if not np.isfinite(tau):
        return None  # rows whose torques are not finite at some lag: nothing to state
    if not np.nanmax(corr_at_zero) >= TORQUE_CLOCK_MIN_CORRELATION:
        # torques that barely resemble the angular acceleration (a no-IMU flight's differentiated attitude: 0.03)
        # time nothing; their peak would read "0 +- 5 ms" with every block agreeing on noise
        return None
    loo = np.array([_crossing(taus, p) for p in peaks[1:]])
    loo = loo[np.isfinite(loo)]
    se = float(jackknife_se(loo)) if len(loo) >= 2 else float("inf")
    half_step = 0.5 * float(np.median(np.concatenate([np.diff(p[0].t) for p in parts])))
    done = np.isfinite(corr_at_zero)
    at = float(np.interp(tau, taus[done], corr_at_zero[done]))
    return CommandLag(tau, float(np.hypot(se, half_step)), rows, at, float(corr_at_zero[0]))


def _window(fd: FlightData, mask: np.ndarray, rows: int) -> tuple[FlightData, np.ndarray]:
    """The flight cut to a stretch of its rows holding at most ``rows`` of ``mask``'s (its middle ones), with
    :data:`LAG_WARM_UP_S` before them for the lag filter to settle, and the mask on it: a long recording's filters
    then run over a bounded stretch, not the whole flight at every lag tried."""
    idx = np.flatnonzero(mask)
    if len(idx) <= rows:
        return fd, mask
    first = (len(idx) - rows) // 2
    start, stop = idx[first], idx[first + rows - 1] + 1
    begin = int(np.searchsorted(fd.t, fd.t[start] - LAG_WARM_UP_S))
    keep = np.zeros(len(fd), bool)
    keep[begin:stop] = True
    inner = mask.copy()
    inner[:start] = False
    inner[stop:] = False
    return fd.subset(keep), inner[keep]


def _peak(shifts: np.ndarray, corr: np.ndarray) -> float:
    """s, the shift at which ``corr`` (one a shift) peaks, refined through a parabola (nan where it is not finite)."""
    if not np.any(np.isfinite(corr)):
        return float("nan")
    k = int(np.nanargmax(corr))
    if k == 0 or k == len(shifts) - 1:
        return float(shifts[k])
    left, mid, right = corr[k - 1:k + 2]
    den = left - 2.0 * mid + right
    return float(shifts[k] + (0.5 * (shifts[1] - shifts[0]) * (left - right) / den if den < 0 else 0.0))


def _crossing(taus: np.ndarray, peaks: np.ndarray) -> float:
    """s, the first lag at which the peak's shift ``peaks`` (one a lag, nan beyond those computed) falls to zero,
    linearly between lattice values: 0 where it is not above zero without a lag, the largest lag where it never
    falls; nan where it cannot be read."""
    if not np.isfinite(peaks[0]):
        return float("nan")
    if peaks[0] <= 0:
        return 0.0
    for j in range(1, len(taus)):
        if not np.isfinite(peaks[j]):
            return float("nan")
        if peaks[j] <= 0:
            return float(taus[j - 1] + (taus[j] - taus[j - 1]) * peaks[j - 1] / (peaks[j - 1] - peaks[j]))
    return float(taus[-1])
