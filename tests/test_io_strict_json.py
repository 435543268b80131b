"""uavturb.io.strict_json: what is printed or written as JSON parses as JSON (no NaN, no Infinity)."""

import json

import numpy as np
import pytest

from uavturb.io.strict_json import dumps_strict, finite_or_none


def _strict_loads(text):
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_numbers_that_are_not_finite_become_null_everywhere():
    o = {"k_M": float("nan"), "inertia": [1.0, np.inf, np.float32(2.5)], "theta": np.array([np.nan, 3.0]),
         "n": np.int64(7), "nested": ({"x": -np.inf},), "text": "NaN"}
    back = _strict_loads(dumps_strict(o))
    assert back == {"k_M": None, "inertia": [1.0, None, 2.5], "theta": [None, 3.0], "n": 7, "nested": [{"x": None}],
                    "text": "NaN"}
    assert finite_or_none(np.float64(1.5)) == 1.5 and type(finite_or_none(np.float64(1.5))) is float
    with pytest.raises(ValueError, match="not JSON"):
        _strict_loads(json.dumps({"a": float("nan")}))  # what the plain dump wrote: refused by a strict reader
    with pytest.raises(TypeError, match="set is not JSON serialisable"):
        dumps_strict({"a": {1, 2}})
