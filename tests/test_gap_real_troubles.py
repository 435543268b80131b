"""The gap finder on flights with real logs' troubles and a known truth (``gap-proof --suite conditions``
rows, shortened): the ground effect is named right, ground contact is found and listed, slow streams are
said, and the delay of late rotor telemetry is found and taken out."""

from __future__ import annotations

import pytest

from uavturb.gap.finder import analyse
from uavturb.io.reader import load_recordings
from uavturb.sim.flights.condition_schema import Conditions
from uavturb.sim.flights.conditions import generate_conditioned_flight, read_truth

GROUND = {"ground_effect": {"mu": 2.0}}


def _flights(root, name, conditions, seeds=(11, 12), duration=40.0):
    paths = []
    for seed in seeds:
        path = root / f"{name}-{seed}"
        generate_conditioned_flight("hex", GROUND, duration=duration, kind="low_passes", seed=seed,
                                    conditions=conditions, out=path)
        paths.append(path)
    return paths


def test_contact_at_both_ends_is_left_out_and_the_ground_effect_named(tmp_path):
    paths = _flights(tmp_path, "contact", Conditions(ground_contact_s=3.0), seeds=(1700, 1701), duration=60.0)  # the proof row's flights, which land at their end
    report, _ = analyse(load_recordings(paths), {})
    named = {e["name"]: e for e in report["effects"]}
    assert list(named) == ["ground_effect"]
    assert named["ground_effect"]["params"]["mu"] == pytest.approx(2.0, rel=0.1)
    for path in paths:
        truth = read_truth(path)["conditions"]["ground_contact"]["intervals_s"]
        found = [(c["t_start"], c["t_end"]) for c in report["ground_contact"] if c["recording"] == str(path)]
        for a, b in truth:  # every true contact is covered by a reported one
            assert any(fa <= a + 0.3 and fb >= b - 0.3 for fa, fb in found), (truth, found)


def test_held_and_late_measured_rotors(tmp_path):
    paths = _flights(tmp_path, "held", Conditions(rate_hz=50, position_hold_hz=9, rotor_hold_hz=3,
                                                   rotor_delay_s=0.06, measured_rotors=True))
    report, _ = analyse(load_recordings(paths), {})
    named = {e["name"]: e for e in report["effects"]}
    assert "ground_effect" in named and named["ground_effect"]["params"]["mu"] == pytest.approx(2.0, rel=0.15)
    assert "battery_sag" not in named and "motor_lag" not in named
    delays = report["streams"]["delays"]  # measured speeds: each recording's delay is estimated and stated
    assert len(delays) == 2 and all("rotors0" in d["describe"] for d in delays)
    for d in delays:  # taken out only where the data pin it down (a 3 Hz stream on gentle passes rarely does)
        assert not d["applied"] or d["lag_s"] == pytest.approx(0.06, abs=3 * d["stderr_s"])
    assert any("rotors0" in why and "too slow" in why for why in report["streams"]["stream_limits"])
    assert any(n["name"] == "battery_sag" for n in report["not_testable"])
