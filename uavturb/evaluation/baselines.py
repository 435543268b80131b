"""Reference points for Table 1: trivial height estimators and where RMSE(f_a) comes from.

Two questions decide whether Table 1's rows can separate on a dataset:

- *How visible is the height?* :func:`bottom_row_height` reads it off the depth image's
  bottom row with the camera geometry alone (no learning): the surface seen by the lowest
  rays is, most of the time, the surface about to be under the vehicle. If this one-liner
  is already close to the learnt models, the encoder and its pre-training have little left
  to win.
- *Which frames make RMSE(f_a)?* ``f_a ~ 1 / d^2`` (:func:`uavturb.physics.ground_effect.phi`),
  so the squared error is made almost entirely by the few frames nearest the ground:
  :func:`fa_error_shares` says how much.

Frames: camera ``z`` forward, ``y`` down, ``x`` right (OpenCV); the camera is pitched down by
``pitch_deg`` from body ``+x``; body tilt is ignored (the estimator does not know it).
Units: metres, degrees, newtons.
"""

from __future__ import annotations

import numpy as np


def bottom_row_height(depth: np.ndarray, K: np.ndarray, pitch_deg: float, rows: int = 1) -> np.ndarray:
    """Height of the camera over what the lowest image rows see, from geometry alone.

    A pixel of row ``v`` looks along ``(x, y, 1)`` with ``y = (v + 0.5 - c_y) / f_y`` (per
    unit of z-depth); pitched down by ``p``, its vertical drop per unit z-depth is
    ``sin p + y cos p``, so the point seen lies ``depth (sin p + y cos p)`` below the camera.
    The estimate is the median over the ``rows`` bottom rows.

    Parameters
    ----------
    depth : (N, H, W) z-depth [m] (pinhole camera, ``K``'s pixel grid).
    K : (3, 3) intrinsics [px].
    pitch_deg : camera pitch below body ``+x`` [deg].
    rows : bottom rows used.

    Returns
    -------
    (N,) height [m]; exact for a level camera over a horizontal floor filling those rows.
    """
    depth = np.asarray(depth, float)
    K = np.asarray(K, float)
    H = depth.shape[1]
    p = np.radians(pitch_deg)
    y = (np.arange(H - rows, H) + 0.5 - K[1, 2]) / K[1, 1]
    drop = depth[:, H - rows:, :] * (np.sin(p) + y[None, :, None] * np.cos(p))
    return np.median(drop.reshape(len(depth), -1), axis=1)


def fa_error_shares(d_true: np.ndarray, fa_true: np.ndarray, fa_pred: np.ndarray,
                    bands: tuple[float, ...] = (0.05, 0.5)) -> dict[str, float]:
    """RMSE(f_a) [N] and the share of its squared error made in each height band.

    Parameters
    ----------
    d_true : (N,) true height [m]; fa_true, fa_pred : (N,) f_a [N].
    bands : band edges [m]: ``d < bands[0]``, ``bands[0] <= d < bands[1]``, ...

    Returns
    -------
    dict: ``rmse_fa``; ``share_d<0.05`` etc. (fractions of the summed squared error, sum 1);
    ``frames_d<0.05`` etc. (fractions of frames).
    """
    d_true, fa_true, fa_pred = (np.asarray(x, float) for x in (d_true, fa_true, fa_pred))
    e2 = (fa_pred - fa_true) ** 2
    total = e2.sum()
    edges = (-np.inf, *bands, np.inf)
    out = {"rmse_fa": float(np.sqrt(e2.mean()))}
    for lo, hi in zip(edges[:-1], edges[1:]):
        name = f"d<{hi:g}" if lo == -np.inf else (f"d>={lo:g}" if hi == np.inf else f"{lo:g}<=d<{hi:g}")
        sel = (d_true >= lo) & (d_true < hi)
        out[f"share_{name}"] = float(e2[sel].sum() / total) if total > 0 else float("nan")
        out[f"frames_{name}"] = float(sel.mean())
    return out
