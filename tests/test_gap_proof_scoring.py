"""How the gap proofs score a report against a known truth (verdicts, parameter errors)."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.experiments.gap_conditions import TOLERANCE, verdict
from uavturb.experiments.proof_scoring import param_error

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
