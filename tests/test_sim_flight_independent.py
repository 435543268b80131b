"""`uavturb generate flight` output read back by an independent reader (numpy + yaml only, no
uavturb.io), and an effect's parameter recovered by plain regression on the law of effects.md."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from uavturb.cli import main


def _csv(path):
    """EuRoC CSV: '#' header, ',' or ', ' separators, integer ns timestamps first."""
    rows = [l for l in path.read_text().splitlines() if l.strip() and not l.startswith("#")]
    t = np.array([int(r.split(",")[0]) for r in rows], dtype=np.int64)
    x = np.array([[float(v) for v in r.split(",")[1:]] for r in rows])
    return t, x


def _rot(q):
    """Rotation matrices (K, 3, 3) of unit quaternions w, x, y, z (body to world)."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def _body_residual(folder):
    """(t_ns, q, v_world, sum of rotor speeds, body residual m a_imu - [0, 0, T] without T's z) on the
    ground-truth timestamps. Only the horizontal body axes are used: there the thrust law drops out."""
    veh = yaml.safe_load((folder / "vehicle.yaml").read_text())
    t_gt, gt = _csv(folder / "mav0" / "state_groundtruth_estimate0" / "data.csv")
    t_imu, imu = _csv(folder / "mav0" / "imu0" / "data.csv")
    t_rot, rot = _csv(folder / "mav0" / "rotors0" / "data.csv")
    lo, hi = max(t_gt[0], t_imu[0], t_rot[0]), min(t_gt[-1], t_imu[-1], t_rot[-1])
    keep = (t_gt >= lo) & (t_gt <= hi)
    t = t_gt[keep]
    q = gt[keep, 3:7] / np.linalg.norm(gt[keep, 3:7], axis=1, keepdims=True)
    v = gt[keep, 7:10]
    b_a = gt[keep, 13:16]
    acc = np.stack([np.interp(t, t_imu, imu[:, 3 + i]) for i in range(3)], 1) - b_a
    w = np.stack([np.interp(t, t_rot, rot[:, i] * veh.get("rotor_speed_scale", 1.0))
                  for i in range(rot.shape[1])], 1)
    return t, q, v, w.sum(1), veh["mass"] * acc


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("indep")
    made = {}
    for name, effects in [("drag", "rotor_drag:k_d=8.06e-5"), ("wind", "wind:f_x=0.3,f_y=-0.2")]:
        assert main(["generate", "flight", "--vehicle", "hex", "--effects", effects, "--duration", "30",
                     "--kind", "mixed", "--seed", "5", "--out", str(root / name)]) == 0
        made[name] = root / name
    return made


def test_rotor_drag_recovered_by_regression(flights):
    t, q, v, wsum, m_acc = _body_residual(flights["drag"])
    v_B = np.einsum("kji,kj->ki", _rot(q), v)
    # effects.md: F = -k_d Wsum R [v_Bx, v_By, 0]  ->  in B: -k_d Wsum v_B,xy
    x = -(wsum[:, None] * v_B[:, :2]).ravel()
    y = m_acc[:, :2].ravel()
    k_d = float(x @ y / (x @ x))
    assert k_d == pytest.approx(8.06e-5, rel=0.10)


def test_wind_recovered_by_regression(flights):
    t, q, v, wsum, m_acc = _body_residual(flights["wind"])
    R = _rot(q)
    # F_B = R^T (f_x, f_y, 0): stack both body horizontal axes, unknowns f_x, f_y
    A = np.concatenate([R[:, :2, 0], R[:, :2, 1]])  # rows (R^T)_x, (R^T)_y = columns of R, on (f_x, f_y)
    y = np.concatenate([m_acc[:, 0], m_acc[:, 1]])
    f = np.linalg.lstsq(A, y, rcond=None)[0]
    assert f[0] == pytest.approx(0.3, rel=0.10) and f[1] == pytest.approx(-0.2, rel=0.10)
