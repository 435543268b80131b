"""What loggers and airframes do to a recording's streams: held values, late rotor telemetry,
measured rotor speeds, a battery's voltage, a thrust axis tilted from the airframe.

Used by :func:`uavturb.sim.flights.conditions.condition` (the laws are stated there, in the module
docstring of :mod:`uavturb.sim.flights.conditions`, and in ``truth.yaml``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from uavturb.io.recording import Battery
from uavturb.physics.dynamics import GRAVITY

#: V, a full 4-cell lithium-polymer pack
FULL_4S_VOLTAGE = 16.8
#: 1/s, the voltage's sag ``V = V0 sqrt(1 - s t)`` without a ``battery_sag`` in the physics (the
#: charge drains while speed-regulated motors keep their thrust): about 2 % a minute
DRAIN_SAG = 7e-4
#: Hz, rows of ``battery0``; V, its noise and resolution
BATTERY_RATE_HZ = 10.0
BATTERY_NOISE_V = 0.005
BATTERY_QUANTUM_V = 0.01


def held_rows(t_ns: np.ndarray, hold_hz: float, phase: float = 0.0) -> np.ndarray:
    """Row each row's value comes from when a stream only updates at ``hold_hz`` [Hz].

    Updates arrive at ``t0 + (k + phase) / hold_hz``; each is written in the first row at or after it,
    with that row's own (fresh) value, and repeated bit for bit until the next one (the first row's
    value holds until the first update).

    Parameters
    ----------
    t_ns : (K,) int64 ns, the stream's row times (increasing)
    hold_hz : Hz, the update rate (below the row rate)
    phase : share of an update period [0, 1) by which the updates come after ``t0 + k / hold_hz``
        (round-robin telemetry: ESC ``c`` of ``n`` at ``c / n``)

    Returns
    -------
    (K,) int index into the rows.
    """
    t_ns = np.asarray(t_ns, np.int64)
    update = np.floor((t_ns - t_ns[0]) * (hold_hz * 1e-9) - phase).astype(np.int64)  # update in force at each row
    first = np.r_[True, update[1:] != update[:-1]]
    return np.maximum.accumulate(np.where(first, np.arange(len(t_ns)), 0))


def delayed_rows(t_ns: np.ndarray, delay_s: float) -> np.ndarray:
    """Row whose value each row shows when a stream's timestamps are ``delay_s`` [s] late: the
    row in force at ``t - delay`` (the first row before the stream's start).

    Returns
    -------
    (K,) int index into the rows.
    """
    t_ns = np.asarray(t_ns, np.int64)
    k = np.searchsorted(t_ns, t_ns - np.int64(round(delay_s * 1e9)), side="right") - 1
    return np.clip(k, 0, len(t_ns) - 1)


def measured_speeds(speeds: np.ndarray, t: np.ndarray, sag: float, quantum: float) -> np.ndarray:
    """What ESC telemetry reports [rad/s] (K, N) for the true rotor speeds ``speeds`` [rad/s] (K, N) at
    ``t`` [s] since the start.

    The simulator writes a battery sag as the thrust coefficient falling at a given speed,
    ``k_T (1 - s t)`` (``effects.md``); on a real vehicle the sagging voltage turns the rotors
    slower, and the ESC measures the speed whose nominal thrust is the true one:
    ``w_meas = w sqrt(1 - s t)``. Quantised to ``quantum`` [rad/s] (0: not)."""
    w = np.asarray(speeds, float) * np.sqrt(np.clip(1.0 - sag * np.asarray(t, float), 0.0, None))[:, None]
    return w if quantum <= 0 else np.round(w / quantum) * quantum


def loaded_voltage(t: np.ndarray, thrust: np.ndarray, v0: float, sag: float, load_sag: float,
                   hover_thrust: float) -> np.ndarray:
    """(K,) V, a battery's voltage at ``t`` [s] under the rotors' true ``thrust`` [N] (K,): the open-circuit
    voltage ``V0 sqrt(1 - s t)`` (:func:`battery_stream`) less the drop across its internal resistance,
    ``V0 load_sag (T / T_hover)^1.5`` (the current goes as the rotors' power, which goes as thrust to the
    power 1.5 by momentum theory): ``load_sag`` is the share of ``V0`` lost at hover (0.05-0.1 on small packs)."""
    ocv = v0 * np.sqrt(np.clip(1.0 - sag * np.asarray(t, float), 0.0, None))
    load = np.clip(np.asarray(thrust, float) / hover_thrust, 0.0, None) ** 1.5
    return ocv - v0 * load_sag * load


def voltage_commands(speeds: np.ndarray, voltage: np.ndarray, v_ref: float, k_V: float) -> np.ndarray:
    """(K, N) rad/s, the commanded speeds a flight controller logs for rotors that turn at ``speeds`` (K, N) under
    the battery's ``voltage`` (K,) [V], where the thrust per commanded speed squared goes as
    ``1 + k_V (V - v_ref)`` (``battery_voltage`` of ``effects.md``'s registry; a duty-cycle command turns the
    rotor faster on a fuller battery): ``w_cmd = w / sqrt(1 + k_V (V - v_ref))``."""
    factor = np.clip(1.0 + k_V * (np.asarray(voltage, float) - v_ref), 1e-3, None)
    return np.asarray(speeds, float) / np.sqrt(factor)[:, None]


def battery_samples(t_ns: np.ndarray, voltage: np.ndarray, rng: np.random.Generator) -> Battery:
    """``battery0`` sampled from a voltage [V] known on rows ``t_ns`` [ns]: every 1 / :data:`BATTERY_RATE_HZ` s,
    noisy and quantised as :func:`battery_stream`'s."""
    period = int(round(1e9 / BATTERY_RATE_HZ))
    out_ns = np.arange(int(t_ns[0]), int(t_ns[-1]) + 1, period, dtype=np.int64)
    v = np.interp(out_ns.astype(float), np.asarray(t_ns, float), voltage) + rng.normal(0.0, BATTERY_NOISE_V,
                                                                                      len(out_ns))
    return Battery(t_ns=out_ns, voltage=np.round(v / BATTERY_QUANTUM_V) * BATTERY_QUANTUM_V)


def battery_stream(t0_ns: int, t1_ns: int, v0: float, sag: float, rng: np.random.Generator) -> Battery:
    """``battery0``: voltage ``V0 sqrt(1 - s t)`` [V] (thrust per speed squared goes as the voltage
    squared, so a ``battery_sag`` of ``s`` is this voltage), noisy, quantised, every
    1 / :data:`BATTERY_RATE_HZ` s from ``t0_ns`` to ``t1_ns``; no current column."""
    period = int(round(1e9 / BATTERY_RATE_HZ))
    t_ns = np.arange(int(t0_ns), int(t1_ns) + 1, period, dtype=np.int64)
    t = (t_ns - t_ns[0]) * 1e-9
    v = v0 * np.sqrt(np.clip(1.0 - sag * t, 0.0, None)) + rng.normal(0.0, BATTERY_NOISE_V, len(t))
    return Battery(t_ns=t_ns, voltage=np.round(v / BATTERY_QUANTUM_V) * BATTERY_QUANTUM_V)


def tilt_rotation(tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    """``R_SB`` (3, 3): B (rotor frame) vectors into S (airframe), the rotation by ``tilt`` about
    ``(-sin az, cos az, 0)`` that takes ``e_z`` to the thrust axis in S,
    ``t = (sin tilt cos az, sin tilt sin az, cos tilt)``."""
    th, az = np.radians(tilt_deg), np.radians(azimuth_deg)
    u = np.array([-np.sin(az), np.cos(az), 0.0])
    K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K


def tilt_push_at_hover(mass: float, tilt_deg: float, azimuth_deg: float, yaw: float) -> dict[str, Any]:
    """The steady push [N] a thrust axis tilted by ``tilt`` towards ``azimuth`` (in the airframe) shows
    to a model that thrusts along the airframe's z, hovering at heading ``yaw`` [rad]:
    ``m g (e_z - R_yaw R_SB^T e_z)``, horizontal part ``m g sin(tilt)`` towards ``yaw + azimuth``;
    in the airframe it is fixed, in W it turns with the heading."""
    th, az = np.radians(tilt_deg), np.radians(azimuth_deg)
    f_body = mass * GRAVITY * np.array([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), 1.0 - np.cos(th)])
    c, s = np.cos(yaw), np.sin(yaw)
    f_w = np.array([c * f_body[0] - s * f_body[1], s * f_body[0] + c * f_body[1], f_body[2]])
    return {"f_x": float(f_w[0]), "f_y": float(f_w[1]), "f_z": float(f_w[2]), "body": f_body.tolist(),
            "heading_rad": float(yaw)}
