"""The contract keys of this round (``recordings.md``): ``rotor_plane_z`` and ``rotor_speed_source`` in
``vehicle.yaml``, the optional ``battery0`` stream, and surface heights measured from the rotor plane
in the readers, the physics and the simulator."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from conftest import make_recording

from uavturb.errors import InputError
from uavturb.io.reader import BATTERY_CSV, VEHICLE_YAML, read_recording
from uavturb.io.recording import Battery
from uavturb.io.vehicle_file import load_vehicle, save_vehicle
from uavturb.io.writer import write_recording
from uavturb.physics import quaternion as quat
from uavturb.physics.effects import parse_effects
from uavturb.physics.vehicle import HEXAROTOR, QUADROTOR, Vehicle
from uavturb.sim.flights.simulate import simulate_flight
from uavturb.sim.core.signals import hover
from uavturb.sysid.flight_data import flight_data


def _vehicle_dict(**extra) -> dict:
    d = QUADROTOR.to_dict()
    d.update(extra)
    return d


def test_new_keys_round_trip_and_defaults(tmp_path):
    v = QUADROTOR.with_params(rotor_plane_z=-0.025, rotor_speed_source="measured")
    save_vehicle(v, tmp_path / "vehicle.yaml")
    assert load_vehicle(tmp_path / "vehicle.yaml") == v
    text = yaml.safe_load((tmp_path / "vehicle.yaml").read_text())
    assert text["rotor_plane_z"] == -0.025 and text["rotor_speed_source"] == "measured"
    # at their defaults the keys are not written: files of earlier versions are unchanged
    save_vehicle(QUADROTOR, tmp_path / "plain.yaml")
    plain = yaml.safe_load((tmp_path / "plain.yaml").read_text())
    assert "rotor_plane_z" not in plain and "rotor_speed_source" not in plain
    back = load_vehicle(tmp_path / "plain.yaml")
    assert back.rotor_plane_z == 0.0 and back.rotor_speed_source == "commanded"


@pytest.mark.parametrize("key, value, message", [
    ("rotor_plane_z", "low", "key 'rotor_plane_z' must be a finite number"),
    ("rotor_plane_z", float("nan"), "key 'rotor_plane_z' must be a finite number"),
    ("rotor_speed_source", "esc", "key 'rotor_speed_source' must be one of commanded, measured"),
])
def test_bad_new_keys_name_the_key(key, value, message):
    with pytest.raises(InputError, match=message):
        Vehicle.from_dict(_vehicle_dict(**{key: value}), where="vehicle.yaml")


def test_rotor_plane_positions_follow_the_attitude():
    v = QUADROTOR.with_params(rotor_plane_z=0.15)
    p = np.array([[1.0, 2.0, 0.5], [0.0, 0.0, 1.0]])
    R = quat.to_rotation_matrix(quat.from_euler(np.array([0.0, np.pi / 2]), np.zeros(2), np.zeros(2)))
    rp = v.rotor_plane_positions(p, R)
    np.testing.assert_allclose(rp[0], [1.0, 2.0, 0.65], atol=1e-12)  # level: 15 cm straight up
    np.testing.assert_allclose(rp[1], [0.0, -0.15, 1.0], atol=1e-12)  # rolled 90 deg: z_B points along -y_W
    assert QUADROTOR.rotor_plane_positions(p, R) is p


def test_battery_round_trip_with_and_without_current(tmp_path):
    rec = make_recording()
    t = rec.ground_truth.t_ns[::20]
    rec.battery = Battery(t_ns=t, voltage=np.linspace(16.8, 15.1, len(t)), current=np.linspace(8.0, 12.5, len(t)))
    write_recording(rec, tmp_path / "a")
    back = read_recording(tmp_path / "a").battery
    assert np.array_equal(back.t_ns, t)
    np.testing.assert_allclose(back.voltage, rec.battery.voltage, rtol=1e-15)
    np.testing.assert_allclose(back.current, rec.battery.current, rtol=1e-15)
    assert (tmp_path / "a" / BATTERY_CSV).read_text().startswith("#timestamp [ns],voltage [V],current [A]\n")
    rec.battery = Battery(t_ns=t, voltage=np.full(len(t), 4.1))
    write_recording(rec, tmp_path / "b")
    back = read_recording(tmp_path / "b").battery
    assert back.current is None and np.all(back.voltage == 4.1)
    rec.battery = None
    write_recording(rec, tmp_path / "c")
    assert read_recording(tmp_path / "c").battery is None


@pytest.mark.parametrize("body, message", [
    ("#timestamp [ns],voltage [V],current [A]\n1,16.0,1.0,3.0\n2,16.0,1.0,3.0\n", "has 4 columns"),
    ("#timestamp [ns],voltage [V]\n1,16.0\n2,-1.0\n", "row 2: battery voltage -1 V is not positive"),
    ("#timestamp [ns],voltage [V]\n1,16.0\n2,abc\n", "line 3"),
    ("#timestamp [ns],voltage [V]\n1,16400\n2,16380\n3,16370\n", "battery voltages of 16380 V \\(median\\), over the "
                                                               "150 V of any multirotor's pack"),
])
def test_bad_battery_file_names_the_file(tmp_path, body, message):
    write_recording(make_recording(), tmp_path / "r")
    path = tmp_path / "r" / BATTERY_CSV
    path.parent.mkdir(parents=True)
    path.write_text(body)
    with pytest.raises(InputError, match=message) as e:
        read_recording(tmp_path / "r")
    assert "battery0/data.csv" in str(e.value)


def _hover_flight(vehicle, z, tmp_path, name):
    rec, truth = simulate_flight(vehicle, hover((0.0, 0.0, z), duration=3.0),
                                 effects=parse_effects("ground_effect:mu=2"), seed=0)
    write_recording(rec, tmp_path / name)
    return rec, truth


@pytest.mark.parametrize("offset", [-0.025, 0.15])
def test_heights_are_the_rotor_planes_in_simulator_and_physics(tmp_path, offset):
    """The simulator's ground effect and the physics' heights use the rotor plane: a hexarotor whose
    rotors sit ``offset`` above its body origin, hovering with the origin at 0.4 m over the default
    room's floor, feels the law at ``0.4 + offset`` and ``flight_data`` reports that height."""
    plain, truth0 = _hover_flight(HEXAROTOR, 0.4, tmp_path, "plain")
    v = HEXAROTOR.with_params(rotor_plane_z=offset)
    rec, truth = _hover_flight(v, 0.4, tmp_path, "offset")
    assert yaml.safe_load((tmp_path / "offset" / VEHICLE_YAML).read_text())["rotor_plane_z"] == offset
    settled = truth.t > 1.0
    np.testing.assert_allclose(truth.d_down[settled], truth0.d_down[settled] + offset, atol=2e-3)
    fd0 = flight_data(read_recording(tmp_path / "plain"))
    fd = flight_data(read_recording(tmp_path / "offset"))
    mid = (fd.t > 1.0) & (fd.t < 2.5)
    np.testing.assert_allclose(np.median(fd.d_down[mid]) - np.median(fd0.d_down[(fd0.t > 1.0) & (fd0.t < 2.5)]),
                               offset, atol=2e-3)
    # closer rotors, more lift: the simulator's effect force follows the rotor plane's height
    lift, lift0 = truth.effect_force[settled, 2].mean(), truth0.effect_force[settled, 2].mean()
    assert (lift > lift0) == (offset < 0)


CRAZYFLIE = {"mass": 0.032, "rotor_count": 4, "arm_length": 0.046, "rotor_angles_deg": [45, 135, -135, -45],
             "rotor_directions": [1, -1, 1, -1], "rotor_radius": 0.0231}


@pytest.mark.parametrize("changes, refused", [
    ({}, False),
    ({"rotor_radius": 0.0462}, True),  # the propeller's diameter given as its radius: the discs overlap 1.42 times
    ({"rotor_radius": 0.0286}, False),  # 24 % larger: overlapping 0.88 times, as staggered frames may
    ({"rotor_count": 8, "rotor_angles_deg": [45, 45, 135, 135, -135, -135, -45, -45],  # coaxial: one angle per pair
      "rotor_directions": [1, -1, -1, 1, 1, -1, -1, 1]}, False),
])
def test_a_rotor_radius_whose_discs_would_overlap_is_refused(changes, refused):
    d = CRAZYFLIE | changes
    if not refused:
        assert Vehicle.from_dict(d, where="v.yaml").rotor_radius == d["rotor_radius"]
        return
    with pytest.raises(InputError) as e:
        Vehicle.from_dict(d, where="v.yaml")
    assert str(e.value) == ("v.yaml: key 'rotor_radius' is 0.0462 m, but rotors 0 and 1 sit 0.0651 m apart "
                            "(arm_length 0.046 m): their discs would overlap 1.42 times over; rotor_radius is half the "
                            "propeller's diameter")
