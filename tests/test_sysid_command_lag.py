"""The rotors' lag behind commanded speeds, read on the torques (``uavturb.sysid.command_lag``): known answers on
simulated flights whose motors lag their recorded commands, and ``identify`` on the lagged speeds."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from uavturb.commands.identify import format_identification, identify_recordings
from uavturb.gap.explain import explanation
from uavturb.io.reader import read_recording
from uavturb.physics.effects import FlightFacts
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight, read_truth
import uavturb.sysid.command_lag as cl
from uavturb.sysid.command_lag import command_lag
from uavturb.sysid.identification import _usable_flights, identify
from uavturb.physics.vehicle import HEXAROTOR
from synthetic import inverse_dynamics_flight


@pytest.fixture(scope="module")
def lagged_commands(tmp_path_factory):
    """A hexarotor's 30 s excitation flight, its motors 60 ms behind PX4-like commands (an idle speed in the map)."""
    path = tmp_path_factory.mktemp("lag") / "cmd"
    generate_conditioned_flight("hex", "motor_lag:tau=0.06", duration=30.0, kind="excitation", seed=16, out=path,
                                conditions=Conditions(motor_commands=True))
    return path


def test_the_lag_is_read_where_the_torques_fit_best(lagged_commands):
    vehicle, fds, _, usable = _usable_flights([read_recording(lagged_commands)], None, "auto", 0.05)
    lag = command_lag(fds, usable.masks, vehicle)
    assert lag.tau_s == pytest.approx(0.06, abs=0.002) and abs(lag.tau_s - 0.06) < 4 * lag.stderr_s + 1e-3
    assert 0.0025 <= lag.stderr_s < 0.005 and lag.decisive and lag.ends[0] < lag.tau_s < lag.ends[1]
    assert lag.correlation > lag.correlation_at_zero


def test_identify_reads_the_lag_and_the_inertia_lands_on_the_truth(lagged_commands, capsys):
    """On the commands as recorded the inertia came out 10-11 % high at 3.6-3.8 stated errors (the torques lead the
    angular acceleration they cause); read on the lagged speeds, with the idle offset read again on them, it lands
    within 1 % and two stated errors of the truth, and residuals read the speeds as identify did."""
    ident = identify_recordings([lagged_commands])
    truth = read_truth(lagged_commands)
    lag = ident.command_lag
    assert lag["applied_s"] == pytest.approx(0.06, abs=0.002) and set(lag["terms"]) >= {"J_x", "J_y"}
    assert ident.to_dict()["command_lag"] == lag
    for i in range(3):
        true = truth["vehicle"]["inertia"][i]
        assert ident.inertia[i] == pytest.approx(true, rel=0.01)
        assert abs(ident.inertia[i] - true) < 2 * ident.inertia_se[i]


def test_exact_speeds_without_a_lag_read_none_and_are_not_lagged(tmp_path):
    path = tmp_path / "exact"
    generate_conditioned_flight("hex", "none", duration=30.0, kind="excitation", seed=16, out=path)
    ident = identify_recordings([path])
    lag = ident.command_lag
    assert lag["tau_s"] < 0.004 and lag["applied_s"] == 0.0 and not lag["decisive"]
    fd_speeds = read_recording(path).rotors.speeds
    assert (ident.rotor_speeds_read(fd_speeds, None) == fd_speeds).all()


def test_the_identification_says_the_lag_it_read(lagged_commands):
    text = format_identification(identify_recordings([lagged_commands]))
    assert re.search(r"the rotors lag the commanded speeds by (59|60)\.\d ± 2\.\d ms", text)
    assert "identified on the lagged speeds" in text


def test_noisy_commands_read_no_lag():
    """Commands recorded with 5 % white noise and no lag: torques of lagged commands fit the angular acceleration
    better only because the lag smooths the noise (a least-squares profile read 45 ms, the inertia 13 % higher still
    than the noise's own attenuation leaves it); the correlation's peak stays within a few milliseconds of zero, and
    nothing is applied."""
    fd, _ = inverse_dynamics_flight(HEXAROTOR, duration=40.0, seed=4, rate_amp=(1.6, 1.6, 0.3), rotor_noise=0.05)
    ident = identify([fd], HEXAROTOR)
    assert ident.command_lag["tau_s"] < 0.005 and ident.command_lag["applied_s"] == 0.0
    assert not ident.command_lag["decisive"] and ident.command_lag["terms"] == {}


def _facts(**torque):
    return FlightFacts(mass=0.034, rotor_count=4, rotor_radius=0.023, k_T=2.9e-8, wsum_hover=4 * 1700.0,
                       speed_p90=0.3, heading_span_deg=10.0, has_imu=True, d_down_min=0.05, d_up_min=np.inf,
                       duration_s=60.0, **torque)


def test_a_motor_lag_explanation_says_what_the_torques_time():
    """Neural-Swarm's 32 g walks: the thrust lags the commands by 71 ms, the roll and pitch torques by 18 +- 5 ms;
    the explanation says the motors account for the torques' lag and the rest is along the thrust alone. Where the
    two agree (the simulator's 30 ms motors, torques 30.4 +- 2.5 ms), and where no torque timing was read, it says
    the rotors lag."""
    apart = explanation("motor_lag", {"tau": 0.071}, _facts(torque_lag_s=0.018, torque_lag_stderr_s=0.005))
    assert apart.startswith("The thrust follows the recorded speeds with a first-order lag of 71 ms")
    assert "lag them by only 18 ± 5 ms" in apart and "a motor time constant of about 18 ms" in apart
    alike = explanation("motor_lag", {"tau": 0.030}, _facts(torque_lag_s=0.0304, torque_lag_stderr_s=0.0025))
    assert alike.startswith("The rotors follow their recorded speeds with a first-order lag of 30 ms")
    assert "lag them by 30 ± 2 ms" in alike or "lag them by 30 ± 3 ms" in alike
    plain = explanation("motor_lag", {"tau": 0.030}, _facts())
    assert plain.startswith("The rotors follow") and "torques" not in plain


def test_a_long_flight_is_read_on_a_bounded_stretch(lagged_commands, monkeypatch):
    """The reading runs its filters over a stretch of at most LAG_ROWS rows from the middle of the flights (and a
    second before it for the lag filter to settle), not the whole flight at every lag: a tenth of the rows reads the
    same lag within its error."""
    vehicle, fds, _, usable = _usable_flights([read_recording(lagged_commands)], None, "auto", 0.05)
    whole = command_lag(fds, usable.masks, vehicle)
    monkeypatch.setattr(cl, "LAG_ROWS", 600)
    part = command_lag(fds, usable.masks, vehicle)
    assert part.rows == 600 < whole.rows
    assert abs(part.tau_s - 0.06) < 2 * part.stderr_s and part.stderr_s >= whole.stderr_s * 0.9


def test_torques_that_barely_resemble_the_angular_acceleration_give_no_reading(lagged_commands):
    """A no-IMU flight's angular acceleration, differentiated from motion-capture attitudes, can be noise: its
    torques correlated 0.03 with it on a probe quadrotor and the peak read "0 ± 5 ms", every block agreeing on
    noise. Under the torques' clock-check correlation at every lag there is no reading."""
    vehicle, fds, _, usable = _usable_flights([read_recording(lagged_commands)], None, "auto", 0.05)
    rng = np.random.default_rng(0)
    noisy = [dataclasses.replace(fd, dw=fd.dw + 50.0 * np.std(fd.dw) * rng.normal(size=fd.dw.shape)) for fd in fds]
    assert command_lag(noisy, usable.masks, vehicle) is None
    assert command_lag(fds, usable.masks, vehicle) is not None
