"""Known answers of the Table 1 reference estimators (uavturb.evaluation.baselines)."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.evaluation.baselines import bottom_row_height, fa_error_shares


@pytest.mark.parametrize("h,pitch", [(0.3, 20.0), (1.2, 20.0), (0.5, 35.0)])
def test_bottom_row_height_of_a_flat_floor_is_the_camera_height(h, pitch):
    H = W = 32
    fy = (H / 2) / np.tan(np.radians(35.0))
    K = np.array([[fy, 0, W / 2], [0, fy, H / 2], [0, 0, 1.0]])
    # z-depth of the floor plane h below a camera pitched down by `pitch`, row v
    y = (np.arange(H) + 0.5 - K[1, 2]) / K[1, 1]
    p = np.radians(pitch)
    rows = np.where(np.sin(p) + y * np.cos(p) > 0, h / (np.sin(p) + y * np.cos(p)), 50.0)
    depth = np.repeat(rows[None, :, None], W, axis=2)
    assert bottom_row_height(depth, K, pitch)[0] == pytest.approx(h, rel=1e-12)
    assert bottom_row_height(depth, K, pitch, rows=3)[0] == pytest.approx(h, rel=1e-12)
    # wrong pitch: wrong height (the test can fail)
    assert abs(bottom_row_height(depth, K, pitch + 10.0)[0] - h) > 0.05 * h


def test_fa_error_shares_split_the_squared_error_by_height():
    d = np.array([0.02, 0.02, 0.3, 1.0])
    fa = np.array([1e-2, 1e-2, 1e-5, 1e-6])
    pred = fa + np.array([3e-3, 0.0, 1e-3, 0.0])
    s = fa_error_shares(d, fa, pred)
    assert s["rmse_fa"] == pytest.approx(np.sqrt((9e-6 + 1e-6) / 4))
    assert s["share_d<0.05"] == pytest.approx(0.9)
    assert s["share_0.05<=d<0.5"] == pytest.approx(0.1)
    assert s["share_d>=0.5"] == 0.0
    assert s["frames_d<0.05"] == 0.5
