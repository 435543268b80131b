"""How far rotors lag the commanded speeds a flight controller records, read on the rotor torques.

Most vehicles record the speeds they command (``vehicle.yaml``'s ``rotor_speed_source``: commanded), and their
motors follow them with a first-order lag (``effects.md``'s ``motor_lag``: RotorS's 12.5-25 ms, Neural-Lander's
45 ms, Neural-Swarm's Crazyflies 60-80 ms as ``uavturb gap`` reads them). Torques computed from the commands then
lead the angular acceleration they cause, and a regression of one on the other reads a smaller gain: the inertia
``l k_T / gain`` comes out high (a hexarotor's commands 30 ms ahead of its rotors: ``J_x``, ``J_y`` 3-4 % high at
2-3 stated errors; 60 ms ahead: 10-13 % at 3.4-3.8).

:func:`command_lag` reads the lag as the time shift ``s`` at which the roll and pitch torques of the commands
correlate best with the angular acceleration they cause (Pearson's r of ``u_1(t - s)`` with ``w_dot_x(t)`` and of
``u_2(t - s)`` with ``w_dot_y(t)``, averaged; the causes filtered as the derivative is, as
:mod:`uavturb.sysid.identification` fits them), on a lattice of ``s``, refined through a parabola at its peak. On
the simulator's motors (a first-order lag) the peak lies at the time constant (32.5 ms for 30, 60 for 60). A shift
is read, not the least squares of the torques on lagged commands: a lag smooths noise out of the commands, and that
fit read 45 ms on noisy commands with no lag at all (the inertia then 13 % high), where the correlation's peak, which
noise lowers at every shift alike, stays at 0-2.5 ms. Its standard error is the jackknife over
:data:`LAG_BLOCKS` contiguous blocks of the flights and half a sample step in quadrature (a command held over a step
acts from its stamp to the next); a lag under two of them is not applied.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from uavturb.numerics.blocks import contiguous_blocks, jackknife_se
from uavturb.physics.effects import lag_rotor_speeds
from uavturb.physics.vehicle import Vehicle
from uavturb.sysid.flight_data import FlightData

#: s, the largest lag searched (beyond every motor in ``effects.md``'s magnitudes and Neural-Swarm's Crazyflies), and
#: s, the lattice's step
COMMAND_LAG_MAX_S, COMMAND_LAG_STEP_S = 0.2, 0.0025


#: contiguous blocks of each flight left out in turn for the lag's jackknife error; a lag applied stands this many
#: standard errors from zero
LAG_BLOCKS, LAG_DECISIVE_Z = 5, 2.0
#: rows the reading uses at most (evenly thinned beyond: 81 shifts of 20,000 rows' two torques are 26 MB)
LAG_ROWS = 20_000


@dataclass(frozen=True)
class CommandLag:
    """A reading of the rotors' lag behind the commanded speeds.

    Attributes
    ----------
    tau_s : s, the shift at which the torques of the commands correlate best with the angular acceleration
    stderr_s : s, its standard error: the jackknife over :data:`LAG_BLOCKS` blocks and half a sample step in
        quadrature (``inf`` where it cannot be formed)
    rows : rows the reading used
    correlation, correlation_at_zero : the torques' mean correlation with the angular acceleration at ``tau_s`` and
        as recorded
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
    total = int(sum(m.sum() for m in masks))
    step = max(1, total // LAG_ROWS)  # a long flight's rows thinned evenly: memory and time stay bounded
    parts = []
    for fd, m in zip(fds, masks):
        if m.sum() < 10:
            continue
        u = fd.matched((fd.rotor_speeds**2) @ M[1:3].T)  # the roll and pitch torques' rotor columns
        idx = np.flatnonzero(m)[::step]
        parts.append((fd.t, u, idx, fd.dw[idx, :2], contiguous_blocks(fd.t[idx], LAG_BLOCKS)))
    rows = sum(len(p[2]) for p in parts)
    if rows < 50:
        return None
    shifts = np.arange(0.0, COMMAND_LAG_MAX_S + COMMAND_LAG_STEP_S / 2, COMMAND_LAG_STEP_S)
    # each flight's torques at its rows shifted by every lattice value, once (the jackknife reuses them)
    shifted = [np.stack([np.stack([np.interp(t[idx] - s, t, u[:, a]) for a in (0, 1)], 1) for s in shifts])
               for t, u, idx, _, _ in parts]

    def profile(left_out: int | None) -> np.ndarray:
        r = []
        for a in (0, 1):
            keep = [p[4] != left_out for p in parts]
            y = np.concatenate([p[3][k, a] for p, k in zip(parts, keep)])
            x = np.concatenate([sh[:, k, a] for sh, k in zip(shifted, keep)], axis=1)  # (shifts, rows)
            x = x - x.mean(axis=1, keepdims=True)
            y = y - y.mean()
            with np.errstate(invalid="ignore", divide="ignore"):
                r.append((x @ y) / np.sqrt((x * x).sum(axis=1) * (y @ y)))
        return np.mean(r, axis=0)

    def peak(corr: np.ndarray) -> float:
        if not np.any(np.isfinite(corr)):
            return float("nan")
        k = int(np.nanargmax(corr))
        if k == 0 or k == len(shifts) - 1:
            return float(shifts[k])
        left, mid, right = corr[k - 1:k + 2]
        den = left - 2.0 * mid + right
        return float(shifts[k] + (0.5 * COMMAND_LAG_STEP_S * (left - right) / den if den < 0 else 0.0))

    corr = profile(None)
    if not np.any(np.isfinite(corr)):
        return None
    tau = peak(corr)
    loo = np.array([peak(profile(b)) for b in range(LAG_BLOCKS)])
    loo = loo[np.isfinite(loo)]
    se = float(jackknife_se(loo)) if len(loo) >= 2 else float("inf")
    # a command held over a sample step acts from its stamp to the next: its timing is known to half a step (the
    # simulator's exact commands, held so, read 2.4 +- 0.4 ms by the jackknife alone; its 30 ms motors 32.5 ms)
    half_step = 0.5 * float(np.median(np.concatenate([np.diff(p[0]) for p in parts])))
    return CommandLag(tau, float(np.hypot(se, half_step)), rows, float(np.nanmax(corr)), float(corr[0]))
