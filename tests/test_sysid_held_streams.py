"""Streams a logger writes faster than they update are read on their updates (``recordings.md``); values
that merely repeat at their resolution are not (sysid/flight_data.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from uavturb.io.recording import GroundTruth
from uavturb.physics.effects import parse_effects
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.sim.flight import SensorNoise, simulate_flight
from uavturb.sim.references import Constant, Reference, Sines
from uavturb.sysid.flight_data import flight_data, held_updates


def _bobbing():
    ref = Reference(Constant(0.0), Constant(0.0), Sines((1.5, 0.3), (0.0, 1.5), (1.5708, 0.0)), Constant(0.0), 12.0,
                    "vertical bobbing")
    rec, truth = simulate_flight(HEXAROTOR, ref, effects=parse_effects("none"), noise=SensorNoise.none(), seed=1)
    return dataclasses.replace(rec, imu=None), truth


def _hold(gt: GroundTruth, every: int) -> GroundTruth:
    """Each value repeated for ``every`` rows (a 200 Hz log of a 200/every Hz estimate)."""
    src = (np.arange(len(gt.t_ns)) // every) * every
    return GroundTruth(gt.t_ns, gt.p[src], gt.q[src], gt.v[src], gt.b_w[src], gt.b_a[src])


def test_held_positions_are_read_on_their_updates():
    rec, truth = _bobbing()
    held = dataclasses.replace(rec, ground_truth=_hold(rec.ground_truth, 20))  # 10 Hz in 200 Hz rows
    gt, _ = held_updates(held)
    assert len(gt.t_ns) == len(rec.ground_truth.t_ns) // 20 + 1  # the updates and the last row
    fd = flight_data(held, window_s=0.3)
    inner = (fd.t > 2.0) & (fd.t < 10.0)
    a_true = np.interp(fd.t, truth.t, np.gradient(truth.x[:, 9], truth.t))  # vertical acceleration [m/s^2]
    err = np.sqrt(np.mean((fd.dv[inner, 2] - a_true[inner]) ** 2))
    assert err < 0.15 * np.std(a_true[inner])
    # differentiating the staircase itself would be far off
    naive = np.gradient(held.ground_truth.v[:, 2], held.ground_truth.t_ns * 1e-9)
    assert np.sqrt(np.mean(naive**2)) > 2 * np.std(a_true[inner])


def test_values_repeated_by_rounding_are_not_a_held_stream():
    rec, _ = _bobbing()
    gt = rec.ground_truth
    rounded = GroundTruth(gt.t_ns, np.round(gt.p, 2), gt.q, np.round(gt.v, 1), gt.b_w, gt.b_a)  # cm, 0.1 m/s
    out, rotors = held_updates(dataclasses.replace(rec, ground_truth=rounded))
    assert out is rounded and rotors is rec.rotors
