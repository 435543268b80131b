"""How the gap proofs score a report against a known truth (verdicts, parameter errors)."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.proof.conditions import THRUST_TILT, TOLERANCE, contact_found, true_effects, verdict
from uavturb.proof.scoring import param_error

WIND = {"wind": {"f_x": -1.84, "f_y": 0.0}}
KNOWN = {**WIND, "rotor_drag": {"k_d": 8.06e-5}, "body_drag": {"c_d": 0.05}}
PHYSICS = set(KNOWN)


def _report(named: dict, ambiguous: tuple = ()) -> dict:
    return {"effects": [{"name": n, "params": p} for n, p in named.items()],
            "ambiguous": [{"candidates": list(c)} for c in ambiguous]}


def test_param_error_is_relative_over_the_parameter_vector():
    assert param_error({"f_x": 3.0, "f_y": 4.0}, {"f_x": 3.0, "f_y": 4.5}) == pytest.approx(0.1)
    assert param_error({"k_d": 2.0}, None) == np.inf


def test_verdicts_known_answers():
    close = {"wind": {"f_x": -1.80, "f_y": 0.01}}
    assert verdict(WIND, PHYSICS, _report(close), KNOWN)[0] == "right"
    assert verdict(WIND, PHYSICS, _report({}, [("wind", "accelerometer_bias")]), KNOWN)[0] == "ambiguous"
    assert verdict(WIND, PHYSICS, _report({}), KNOWN)[0] == "missed"
    far = {"wind": {"f_x": -1.84 * (1 + 2 * TOLERANCE), "f_y": 0.0}}
    assert verdict(WIND, PHYSICS, _report(far), KNOWN)[0] == "WRONG"
    # a surface effect the flights do not have
    assert verdict(WIND, PHYSICS, _report({**close, "ground_effect": {"mu": 2.0}}), KNOWN)[0] == "WRONG"


def test_an_effect_beside_the_target_named_far_off_is_wrong():
    """The wind-tunnel case: the push is right, but rotor drag named with body drag folded in."""
    blended = {"wind": {"f_x": -1.84, "f_y": 0.0}, "rotor_drag": {"k_d": 1.75e-4}}
    state, errors = verdict(WIND, PHYSICS, _report(blended), KNOWN)
    assert state == "WRONG" and errors["wind"] == pytest.approx(0.0)
    honest = {"wind": {"f_x": -1.84, "f_y": 0.0}, "rotor_drag": {"k_d": 8.4e-5}}
    assert verdict(WIND, PHYSICS, _report(honest), KNOWN)[0] == "right"
    # without the other effects' truths only the targets are scored (the old rule)
    assert verdict(WIND, PHYSICS, _report(blended))[0] == "right"


def test_nothing_may_be_named_beside_a_look_alike():
    """A thrust axis tilted 1.5 deg at a fixed heading: a steady push that is no wind."""
    physics: set[str] = set()
    push = {"wind": {"f_x": 0.33, "f_y": 0.19}}
    assert verdict({}, physics, _report({}), {}, look_alikes=(THRUST_TILT,))[0] == "right"
    assert verdict({}, physics, _report({}, [("wind", THRUST_TILT)]), {}, look_alikes=(THRUST_TILT,))[0] == "right"
    assert verdict({}, physics, _report({THRUST_TILT: {"tilt_deg": 1.5}}), {}, look_alikes=(THRUST_TILT,))[0] == "right"
    assert verdict({}, physics, _report(push), {}, look_alikes=(THRUST_TILT,))[0] == "WRONG"


def test_effects_hidden_by_measured_speeds_are_not_physics():
    truth = {"effects": {"battery_sag": {"s": 1e-3}, "motor_lag": {"tau": 0.03}}, "equivalent_effects": {},
             "invisible_effects": ["battery_sag", "motor_lag"]}
    known, physics = true_effects([truth, truth])
    assert physics == set() and known == {}
    assert verdict({}, physics, _report({"battery_sag": {"s": 1e-3}}), known)[0] == "WRONG"
    assert verdict({}, physics, _report({}, [("battery_sag", "thrust_coefficient")]), known)[0] == "right"


def test_ground_contact_must_be_found():
    ge = {"ground_effect": {"mu": 2.0}}
    truth = {"rec-0": [[0.0, 3.0], [60.0, 63.0]]}
    found = [{"recording": "/x/rec-0", "t_start": 0.0, "t_end": 2.9}, {"recording": "/x/rec-0", "t_start": 60.2,
                                                                       "t_end": 63.0}]
    assert contact_found(truth, found) and not contact_found(truth, found[:1])
    assert not contact_found(truth, [{**c, "recording": "/x/rec-1"} for c in found])
    report = {**_report({"ground_effect": {"mu": 2.1}}), "ground_contact": found}
    assert verdict(ge, set(ge), report, ge, contact=truth)[0] == "right"
    assert verdict(ge, set(ge), {**report, "ground_contact": []}, ge, contact=truth)[0] == "missed"
    # a floor carrying the vehicle read as ground effect: mu far off is WRONG whatever the contact
    far = {**report, "effects": [{"name": "ground_effect", "params": {"mu": 3.5}}]}
    assert verdict(ge, set(ge), far, ge, contact=truth)[0] == "WRONG"
