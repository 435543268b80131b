"""The battery's voltage (``battery0``) read by the gap finder: thrust per commanded rotor speed squared follows it
(``battery_voltage``, an own-named law beside ``effects.md``'s ``battery_sag``). Known answers from flights simulated
with a battery sagging under load and commands that are duty cycles; bad inputs; look-alikes."""

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.gap.design import THRUST_FACTOR, effect_inputs, thrust_columns
from uavturb.gap.finder import analyse
from uavturb.gap.fit import fit_model
from uavturb.io.reader import load_recordings
from uavturb.io.recording import Battery
from uavturb.physics.effects import EFFECTS
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight, read_truth
from uavturb.sim.flights.stream_troubles import (BATTERY_NOISE_V, BATTERY_QUANTUM_V, loaded_voltage,
                                                 voltage_commands)
from uavturb.sysid.flight_data import battery_voltage, battery_voltage_noise

#: V, a full 4S pack; the share it loses at hover; k_V of a motor driven at a duty cycle (k_V V = 2)
V0, LOAD_SAG = 16.8, 0.08
K_V = 2.0 / (V0 * (1 - LOAD_SAG))


def test_voltage_commands_round_trip():
    """Commands logged for true speeds ``w`` under a voltage give back ``w`` through the law's factor."""
    rng = np.random.default_rng(0)
    w = rng.uniform(300, 600, (50, 4))
    volts = rng.uniform(14.0, 16.8, 50)
    cmd = voltage_commands(w, volts, 15.5, 0.13)
    assert np.allclose(cmd**2 * (1 + 0.13 * (volts - 15.5))[:, None], w**2)
    assert np.allclose(voltage_commands(w, volts, 15.5, 0.0), w)


def test_loaded_voltage_known_answers():
    """Open-circuit voltage at rest, less the load's share at hover, growing as thrust^1.5."""
    t = np.array([0.0, 0.0, 0.0, 100.0])
    thrust = np.array([0.0, 10.0, 40.0, 0.0])  # N; hover at 10 N
    v = loaded_voltage(t, thrust, 16.0, 1e-3, 0.05, 10.0)
    assert v[0] == pytest.approx(16.0)
    assert v[1] == pytest.approx(16.0 * 0.95)
    assert v[2] == pytest.approx(16.0 - 16.0 * 0.05 * 8.0)  # 4x the thrust: 8x the drop
    assert v[3] == pytest.approx(16.0 * np.sqrt(1 - 0.1))


def test_battery_voltage_on_the_time_base():
    """Interpolated between the updates of a held stream, nan outside its span, None without one."""
    from uavturb.io.recording import Recording

    t_ns = np.arange(0, 10) * 100_000_000  # 10 Hz rows, each value written twice (an update every 0.2 s)
    volts = np.repeat([16.0, 15.8, 15.6, 15.4, 15.2], 2)
    rec = Recording.__new__(Recording)
    object.__setattr__(rec, "battery", Battery(t_ns=t_ns, voltage=volts))
    at = np.array([0, 100_000_000, 300_000_000, 900_000_000, 950_000_000], np.int64)
    v = battery_voltage(rec, at)
    # updates at 0, 0.2, 0.4, 0.6, 0.8 s and the last row (0.9 s, holding 15.2)
    assert v[0] == pytest.approx(16.0) and v[1] == pytest.approx(15.9) and v[2] == pytest.approx(15.7)
    assert v[3] == pytest.approx(15.2) and np.isnan(v[4])
    object.__setattr__(rec, "battery", None)
    assert battery_voltage(rec, at) is None


def _battery_recording(t_ns: np.ndarray, volts: np.ndarray):
    from uavturb.io.recording import Recording

    rec = Recording.__new__(Recording)
    object.__setattr__(rec, "battery", Battery(t_ns=t_ns, voltage=volts))
    return rec


def test_battery_voltage_noise_known_answers():
    """A voltage draining and sagging smoothly, sampled at 10 Hz with 5 mV of white noise: read at 100 Hz rows, the
    noise's variance at a row is 2/3 of the samples' (linear interpolation: all of it at a sample, half midway);
    at the samples themselves all of it. Without noise it reads the curvature's share only (0.1 mV), and rounded to
    10 mV without noise none."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 120.0, 0.1)
    smooth = 16.0 - 0.004 * t - 0.05 * np.sin(2 * np.pi * t / 7.0)
    t_ns = (t * 1e9).astype(np.int64)
    rows = np.arange(int(t_ns[0]), int(t_ns[-1]), 10_000_000, dtype=np.int64)
    noisy = _battery_recording(t_ns, smooth + rng.normal(0.0, 0.005, len(t)))
    assert battery_voltage_noise(noisy, rows) == pytest.approx(2.0 / 3.0 * 0.005**2, rel=0.15)
    assert battery_voltage_noise(noisy, t_ns) == pytest.approx(0.005**2, rel=0.15)
    assert battery_voltage_noise(_battery_recording(t_ns, smooth), rows) < 0.0003**2  # its curvature only
    assert battery_voltage_noise(_battery_recording(t_ns, np.round(smooth / 0.01) * 0.01), rows) == 0.0
    assert battery_voltage_noise(_battery_recording(t_ns[:3], smooth[:3]), rows) is None


def test_the_law_is_one_registry_entry():
    """Declared once: its thrust factor, its coefficient in the design, its range stated on k_V V."""
    spec = EFFECTS["battery_voltage"]
    assert spec.params == ("k_V",) and spec.units == ("1/V",) and spec.alternative_to == "battery_sag"
    assert THRUST_FACTOR == {"battery_sag": "k_T*s", "battery_voltage": "k_T*k_V"}
    from uavturb.physics.effects import FlightFacts

    facts = FlightFacts(mass=1.0, rotor_count=4, rotor_radius=0.1, k_T=1e-5, wsum_hover=1000.0, speed_p90=1.0,
                        heading_span_deg=90.0, has_imu=True, d_down_min=1.0, d_up_min=np.inf, duration_s=60.0,
                        voltage_mean=15.0, voltage_span=1.0)
    assert spec.physical_range.violation({"k_V": 2.0 / 15.0}, facts) is None
    assert "outside" in spec.physical_range.violation({"k_V": 0.25}, facts)  # k_V V = 3.75
    # a probe's payload taken on over a flight on commanded speeds was named battery_sag: the explanation says so
    assert EFFECTS["battery_sag"].explain({"s": 1e-3}, facts).endswith(
        "(A mass that grows by 6 % over the flight, a payload taken on, reads alike on commanded speeds.)")


@pytest.fixture(scope="module")
def loaded_flights(tmp_path_factory):
    """Two quadrotor flights, commanded speeds (duty cycles) whose thrust follows a 4S battery sagging 8 % at
    hover, no surface effect; the second at a 3 % higher thrust level."""
    root = tmp_path_factory.mktemp("volts")
    paths = []
    for seed, level in ((1, 1.0), (2, 1.03)):
        path = root / f"v{seed}"
        generate_conditioned_flight("quad", f"battery_voltage:k_V={K_V}", duration=60.0, kind="mixed", seed=seed,
                                    conditions=Conditions(battery_voltage=V0, battery_load_sag=LOAD_SAG,
                                                          thrust_level=level), out=path)
        paths.append(path)
    return paths


def test_the_simulated_commands_and_battery_follow_the_law(loaded_flights):
    truth = read_truth(loaded_flights[0])
    assert truth["equivalent_effects"] == {"battery_voltage": {"k_V": pytest.approx(K_V)}}
    assert truth["conditions"]["battery"]["load_sag"] == LOAD_SAG
    (rec,) = load_recordings(loaded_flights[:1])
    assert rec.battery is not None and np.ptp(rec.battery.voltage) > 0.5  # manoeuvres and drain: volts of span


def test_the_flight_rows_read_the_battery_stream_once_for_its_voltage_and_noise(loaded_flights, monkeypatch):
    from uavturb.sysid import flight_data as fd_module

    (rec,) = load_recordings(loaded_flights[:1])
    reads = []
    real = fd_module._battery_samples
    monkeypatch.setattr(fd_module, "_battery_samples", lambda r: reads.append(r) or real(r))
    fd = fd_module.flight_data(rec)
    assert len(reads) == 1
    assert np.array_equal(fd.voltage, battery_voltage(rec, fd.t_ns), equal_nan=True)
    assert fd.voltage_noise_v2 == battery_voltage_noise(rec, fd.t_ns) > 0


def test_the_design_column_is_the_voltage_times_the_thrust(loaded_flights):
    """``k_T*k_V``'s column is ``(V - V_mean) S R e_z`` on every axis of W."""
    report, extras = analyse(load_recordings(loaded_flights), {})
    data = extras["data"]
    D, names = thrust_columns(data, {"battery_voltage"}, data.S, np.zeros(len(data)))
    assert names == ["k_T", "k_T*k_V"]
    K = len(data)
    expected = (effect_inputs(data).voltage_dev * data.S)[:, None] * data.R[:, :, 2]
    assert np.allclose(D[:, 1].reshape(3, K).T, expected)
    # each recording's deviation has mean zero over its rows in flight (its level is the thrust level's)
    dense = data if data.dense is None else data.dense
    for g in np.unique(dense.group):
        assert abs(np.mean(dense.voltage_dev[dense.group == g])) < 0.02


def test_a_load_sagging_battery_is_named_with_its_voltage(loaded_flights):
    """Named as ``battery_voltage`` (not the law in time), k_V within two stated errors and 15 % of the truth; no
    surface effect named on flights with none."""
    report, extras = analyse(load_recordings(loaded_flights), {})
    named = {e["name"]: e for e in report["effects"]}
    assert "battery_voltage" in named and "battery_sag" not in named, list(named)
    assert not any(EFFECTS[n].surface for n in named)
    e = named["battery_voltage"]
    k_V, se = e["params"]["k_V"], e["stderr"]["k_V"]
    assert k_V == pytest.approx(K_V, rel=0.15) and abs(k_V - K_V) < 2 * se
    assert "per volt" in e["explanation"] and e["heldout_rmse_after_N"] < 0.8 * e["heldout_rmse_before_N"]
    assert any("battery0" in line and "read by battery_voltage" in line for line in report["streams"]["streams"])
    # the stream's noise read from its samples: white and its rounding's, 2/3 of it at a row between them
    noise = 2.0 / 3.0 * (BATTERY_NOISE_V**2 + BATTERY_QUANTUM_V**2 / 12.0)
    assert extras["data"].voltage_noise == {"v1": pytest.approx(noise, rel=0.25), "v2": pytest.approx(noise, rel=0.25)}
    assert report["nominal"]["rotor_speed_offset"]["voltage_noise_rad_s"] >= 0.0
    fit = fit_model(extras["data"], {"battery_voltage"})
    assert fit.effect_params("battery_voltage")[0]["k_V"] == pytest.approx(K_V, rel=0.1)


def test_not_testable_without_a_voltage_or_with_measured_speeds(tmp_path):
    """No battery0: the voltage law is not testable, and the report says what to log; measured speeds already show
    the voltage."""
    path = tmp_path / "plain"
    generate_conditioned_flight("quad", "none", duration=30.0, kind="mixed", seed=3, out=path)
    report, _ = analyse(load_recordings([path]), {})
    why = {n["name"]: n for n in report["not_testable"]}
    assert "battery_voltage" in why and "battery0" in why["battery_voltage"]["to_separate"]
    assert "battery_sag" not in why
    measured = tmp_path / "measured"
    generate_conditioned_flight("quad", "none", duration=30.0, kind="mixed", seed=3, out=measured,
                                conditions=Conditions(measured_rotors=True, battery_voltage=V0))
    report, _ = analyse(load_recordings([measured]), {})
    why = {n["name"]: n for n in report["not_testable"]}
    assert "measured" in why["battery_voltage"]["why"] and "measured" in why["battery_sag"]["why"]


def test_bad_battery_options_fail_in_one_line():
    with pytest.raises(InputError, match="--battery-load-sag.*--battery-voltage"):
        Conditions(battery_load_sag=0.05)
    with pytest.raises(InputError, match="battery_voltage needs --battery-voltage"):
        generate_conditioned_flight("quad", "battery_voltage:k_V=0.1", duration=5.0)
    with pytest.raises(InputError, match="give one"):
        generate_conditioned_flight("quad", "battery_voltage:k_V=0.1,battery_sag:s=1e-3", duration=5.0,
                                    conditions=Conditions(battery_voltage=V0))
    from uavturb.sim.flights.simulate import generate_flight

    with pytest.raises(InputError, match="not a force"):
        generate_flight(vehicle="quad", effects="battery_voltage:k_V=0.1", duration=5.0)


def test_not_a_simulator_force():
    """What logged commands mean is no force of a simulator: --sim-effects refuses it, --apply leaves it out."""
    from uavturb.gap.finder import parse_sim_effects

    assert not EFFECTS["battery_voltage"].simulated and all(e.simulated for n, e in EFFECTS.items()
                                                            if n != "battery_voltage")
    with pytest.raises(InputError, match="not a force"):
        parse_sim_effects("ground_effect,battery_voltage")


def test_apply_writes_the_simulators_forces_only(loaded_flights, tmp_path):
    from uavturb.commands.gap import gap
    from uavturb.io.physics_config import load_physics_config

    conf = tmp_path / "applied.yaml"
    report = gap(loaded_flights, tmp_path / "rep", sim_effects="none", apply=conf, log_mlflow=False)
    assert "battery_voltage" in {e["name"] for e in report["effects"]}
    assert "battery_voltage" not in load_physics_config(conf)["effects"]
