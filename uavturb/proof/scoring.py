"""How the gap proofs score the finder against a known truth: the accelerometer bias every proof
flight hides from its state file, and the relative error of a named effect's parameters."""

from __future__ import annotations

import numpy as np

#: m/s^2 in B: an accelerometer bias the state file does not know (its b_a is the true bias minus
#: this), on every flight of the proof: a steady wind must be told from it by the heading changes
HIDDEN_BIAS = (0.10, -0.08, 0.05)


def with_hidden_bias(rec, bias=HIDDEN_BIAS):
    """``rec`` with ``bias`` [m/s^2, B] added to its accelerometer and not to the state file's b_a."""
    import dataclasses

    return dataclasses.replace(rec, imu=dataclasses.replace(rec.imu, acc=rec.imu.acc + np.asarray(bias, float)))


def param_error(truth: dict[str, float], fitted: dict[str, float] | None) -> float:
    """Relative error of an effect's parameters: ``|fitted - truth| / |truth|`` over its parameter
    vector (wind: the force vector); ``inf`` where the effect was not named."""
    if fitted is None:
        return float("inf")
    keys = list(truth)
    t = np.array([truth[k] for k in keys])
    f = np.array([fitted[k] for k in keys])
    return float(np.linalg.norm(f - t) / np.linalg.norm(t))

