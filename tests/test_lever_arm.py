"""A lever arm between the recorded origin and the centre of mass, read from the rotation's accelerations
(``uavturb.sysid.lever_arm``) and taken out by the gap finder: flights in a EuRoC-like sensor frame whose
``T_BS`` puts S 8 cm forward and 6 cm under the centre of mass, with that translation left out of
``vehicle.yaml``."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from uavturb.gap.finder import analyse
from uavturb.io.body_frame import moved_origin
from uavturb.io.reader import load_recordings, read_recording
from uavturb.io.vehicle_file import load_vehicle, save_vehicle
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import EUROC_T_BS, generate_conditioned_flight
from uavturb.sysid.flight_data import flight_data
from uavturb.sysid.lever_arm import PRACTICAL_M, lever_arm

from other_vehicles import HEAVY_HEX

LEVER = EUROC_T_BS[:3, 3]  # m, S's origin in B


def _without_translation(path) -> None:
    """``vehicle.yaml``'s ``T_BS`` keeps its rotation and loses its translation (the lever arm)."""
    vehicle = load_vehicle(path / "vehicle.yaml")
    T = np.array(vehicle.T_BS, float)
    T[:3, 3] = 0.0
    save_vehicle(dataclasses.replace(vehicle, T_BS=tuple(map(tuple, T))), path / "vehicle.yaml")


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Two minutes of a 2.5 kg hexarotor's brisk flight under a ground effect (mu = 2) and rotor drag."""
    root = tmp_path_factory.mktemp("lever")
    vehicle = root / "hex25.yaml"
    vehicle.write_text(HEAVY_HEX)
    paths = []
    for seed in (201, 202):
        path = root / f"euroc-{seed}"
        generate_conditioned_flight(str(vehicle), "ground_effect:mu=2,rotor_drag", duration=60.0, kind="mixed",
                                    seed=seed, conditions=Conditions(sensor_frame="euroc"), out=path)
        paths.append(path)
    return paths


def test_a_lever_arm_left_out_of_t_bs_is_read_from_the_rotation(flights, tmp_path):
    given = lever_arm(flight_data(read_recording(flights[0])))
    assert not given.decisive and np.all(np.abs(given.r_m) < np.maximum(4 * given.stderr_m, 0.005))
    copy = tmp_path / "copy"
    shutil.copytree(flights[0], copy)
    _without_translation(copy)
    found = lever_arm(flight_data(read_recording(copy)))
    assert found.decisive and np.linalg.norm(found.r_m) > PRACTICAL_M
    assert np.all(np.abs(found.r_m - LEVER) < 4 * found.stderr_m + 0.002)
    assert found.stderr_m[2] < 0.005  # roll and pitch accelerations pin the vertical component to millimetres


def test_the_lever_arm_built_in_chunks_is_the_one_built_whole(flights, monkeypatch):
    """The regressors are built ``DESIGN_CHUNK`` rows at a time into the kept rows' arrays (memory): any chunk size
    reads the same lever arm, errors and rows, to the bit."""
    from uavturb.sysid import lever_arm as module

    fd = flight_data(read_recording(flights[0]))
    whole = lever_arm(fd)
    monkeypatch.setattr(module, "DESIGN_CHUNK", 997)
    cut = lever_arm(fd)
    assert whole.rows == cut.rows > 10_000 and whole.accel_rms == cut.accel_rms and whole.decisive == cut.decisive
    np.testing.assert_array_equal(whole.r_m, cut.r_m)
    np.testing.assert_array_equal(whole.stderr_m, cut.stderr_m)


def test_moving_the_origin_back_gives_the_recording_with_its_lever_arm(flights, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(flights[0], copy)
    _without_translation(copy)
    truth, short = read_recording(flights[0]), read_recording(copy)
    moved = moved_origin(short, LEVER, keep_rotor_plane=False)
    np.testing.assert_allclose(moved.ground_truth.p, truth.ground_truth.p, atol=1e-9)
    np.testing.assert_allclose(moved.ground_truth.v, truth.ground_truth.v, atol=1e-9)
    np.testing.assert_allclose(moved.imu.acc, truth.imu.acc, atol=1e-6)
    np.testing.assert_allclose(moved.vehicle.T_BS_matrix, truth.vehicle.T_BS_matrix, atol=1e-12)
    assert moved.vehicle.rotor_plane_z == 0.0
    kept = moved_origin(dataclasses.replace(short, vehicle=dataclasses.replace(short.vehicle, rotor_plane_z=0.1)),
                        LEVER, keep_rotor_plane=True)
    assert kept.vehicle.rotor_plane_z == pytest.approx(0.1 + LEVER[2])


def test_gap_takes_the_lever_arm_out_and_says_so(flights, tmp_path):
    copies = []
    for path in flights:
        copy = tmp_path / path.name
        shutil.copytree(path, copy)
        _without_translation(copy)
        copies.append(copy)
    report, _ = analyse(load_recordings(copies), {})
    (ground,) = [e for e in report["effects"] if e["name"] == "ground_effect"]
    assert abs(ground["params"]["mu"] - 2.0) < 2 * ground["stderr"]["mu"]
    assert [lever["recording"] for lever in report["streams"]["lever_arms"]] == [str(c) for c in copies]
    for lever in report["streams"]["lever_arms"]:
        assert np.all(np.abs(np.array(lever["r_m"]) - LEVER) < 4 * np.array(lever["stderr_m"]) + 0.002)
        assert lever["decisive"] and lever["moved_m"] == [0.0, 0.0, lever["r_m"][2]]  # the height alone
    assert report["height_uncertainty_m"] >= abs(report["streams"]["lever_arms"][0]["r_m"][2])
    lines = [line for line in report["streams"]["streams"] if "the streams were moved 6 cm up to the centre" in line]
    assert len(lines) == 2 and "set T_BS's translation" in lines[0]
