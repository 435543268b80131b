"""A crash's or lost tracking's tail (io/crash.py): cut from every stream where the body origin goes under the
floor and the vehicle does not fly on, with a note; kept where the vehicle flies on (then the floor is what is
wrong); the checks that read the whole recording read only what flies."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uavturb.io.consistency import check_position_velocity
from uavturb.io.crash import CUT_MARGIN_S, UNDER_FLOOR_M, without_lost_tail
from uavturb.io.reader import read_recording
from uavturb.io.recording import GroundTruth, Rotors
from uavturb.sim.flights.simulate import generate_flight


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    path = tmp_path_factory.mktemp("crash") / "flight"
    generate_flight(vehicle="hex", effects="none", duration=12.0, kind="mixed", seed=3, out=path)
    return read_recording(path)


def _crashed(rec, fly_on: bool = False):
    """``rec`` whose motors stop at 9 s (or keep turning: ``fly_on``) and whose estimate sinks from 10 s on, 1 m/s
    under the floor, its velocity left at zero (an onboard estimate running on after the motors cut)."""
    gt, rot = rec.ground_truth, rec.rotors
    t = rec.seconds(gt.t_ns)
    floor = float(np.min(rec.points[:, 2]))
    p = gt.p.copy()
    sink = t >= 10.0
    p[sink, 2] = floor - 0.01 - 1.0 * (t[sink] - 10.0)
    speeds = rot.speeds.copy()
    if not fly_on:
        speeds[rec.seconds(rot.t_ns) >= 9.0] = 0.0
    return dataclasses.replace(rec, ground_truth=GroundTruth(gt.t_ns, p, gt.q, gt.v, gt.b_w, gt.b_a),
                               rotors=Rotors(rot.t_ns, speeds))


def test_a_crash_tail_is_cut_from_every_stream_and_said(flight):
    crashed = _crashed(flight)
    cut, note = without_lost_tail(crashed)
    t = crashed.seconds(crashed.ground_truth.t_ns)
    floor = float(np.min(crashed.points[:, 2]))
    first = t[np.flatnonzero(crashed.ground_truth.p[:, 2] < floor - UNDER_FLOOR_M)[0]]
    assert first == pytest.approx(10.04, abs=0.02)  # 1 cm under the floor at 10 s, 5 cm 40 ms later
    end = first - CUT_MARGIN_S
    for stream, rows in ((cut.ground_truth, ("p", "q", "v", "b_w", "b_a")), (cut.imu, ("gyro", "acc")),
                         (cut.rotors, ("speeds",))):
        ts = cut.seconds(stream.t_ns)
        assert ts.max() < end and ts.max() > end - 0.05
        assert all(len(getattr(stream, name)) == len(ts) for name in rows)
    assert np.array_equal(cut.imu.T_BS, crashed.imu.T_BS)  # not a stream of rows: kept whole
    assert note.startswith(f"{flight.path}/mav0/state_groundtruth_estimate0/data.csv: from {first:.1f} s the state "
                           "estimate lies under the floor (up to ")
    assert f"every stream's rows from {end:.1f} s on (" in note and "a crash, or tracking lost" in note
    np.testing.assert_array_equal(crashed.ground_truth.p[:5], cut.ground_truth.p[:5])  # the rest as it was
    # the whole recording's positions against its velocities: the sinking tail no longer counts
    check_position_velocity(crashed)


def test_a_vehicle_that_flies_on_under_the_floor_keeps_its_rows(flight):
    """The rotors turn on after the heights go under the floor: no crash, the floor (or the heights' frame) is
    wrong, and what the checks say of it stands."""
    flying = _crashed(flight, fly_on=True)
    assert without_lost_tail(flying) == (flying, None)
    assert without_lost_tail(flight) == (flight, None)  # nothing under the floor
    no_cloud = dataclasses.replace(_crashed(flight), points=None)
    assert without_lost_tail(no_cloud) == (no_cloud, None)  # no floor known
