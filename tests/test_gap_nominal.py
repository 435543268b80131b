"""The nominal model's unknowns cannot swallow an effect (sysid/nominal.py), and stated errors are honest
(gap/uncertainty.py): known answers on data the tests make."""

from __future__ import annotations

import copy
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from uavturb.cli import main
from uavturb.gap.decide import can_test_alone
from uavturb.gap.design import MIN_ROWS, GapData, apply_thrust_levels
from uavturb.gap.finder import _nominal, _thrust_laws_left_open, analyse, composed_offset, read_on_moved_speeds
from uavturb.gap.named_errors import at_stated_offset, cross_checked, curve_named_thrust_map, curves_at_open_offsets
from uavturb.gap.fit import ModelFit, fit_model
from uavturb.sysid.nominal import (UNREAD_OFFSET_SPAN, ThrustLevels, level_voltage_slope, matched_height_levels,
                                   SpeedOffset, offset_cells, speed_offset, stated_offset, thrust_levels)
from uavturb.gap.preparation import MIN_DELAY_S, TELEMETRY_DELAY_MAX_S, rotor_speeds_moved, timing_interval
from uavturb.gap.surface_laws import finder_surface_curve
from uavturb.gap.uncertainty import (
    HEIGHT_REFERENCE_M,
    Refits,
    command_sampling_term,
    error_budget,
    honest_stderr,
    thrust_map_term,
    timing_term,
    with_curve_check,
    with_systematic,
)
from uavturb.io.reader import read_recording
from uavturb.io.recording import Rotors
from uavturb.physics import quaternion as quat
from uavturb.physics.dynamics import GRAVITY
from uavturb.physics.ground_effect import force_ratio
from uavturb.numerics.blocks import block_mean_and_se
from uavturb.sysid.accelerometer import anchored_bias

MASS, K_T, R_ROTOR = 1.5, 8.5e-6, 0.1


def test_block_mean_and_se_counts_blocks_not_samples():
    rng = np.random.default_rng(0)
    labels = np.repeat(np.arange(50), 100)  # 50 blocks of 100 identical-offset samples
    x = np.repeat(rng.normal(0, 1.0, 50), 100) + rng.normal(0, 0.01, 5000)
    mean, se = block_mean_and_se(x, labels)
    assert se[0] == pytest.approx(1.0 / np.sqrt(50), rel=0.25)  # sample-wise it would be 1/sqrt(5000)


def test_anchored_bias_is_what_the_imu_reads_beyond_the_motion_capture():
    rng = np.random.default_rng(1)
    K = 6000
    t = np.arange(K) * 0.005
    R = quat.to_rotation_matrix(quat.from_euler(0.1 * np.sin(t), 0.1 * np.cos(0.7 * t), 0.3 * t))
    dv = np.stack([np.sin(t), np.cos(1.3 * t), 0.5 * np.sin(0.4 * t)], axis=1)
    bias = np.array([0.15, -0.10, 0.65])  # a z bias of the size that swallowed k_T on real flights
    acc = np.einsum("kji,kj->ki", R, dv + [0, 0, GRAVITY]) + bias + rng.normal(0, 0.05, (K, 3))
    dv_noisy = dv + rng.normal(0, 0.2, (K, 3))  # differentiated motion capture is noisier
    found = anchored_bias(t, R, acc, dv_noisy, np.ones(K, bool))
    np.testing.assert_allclose(found.b, bias, atol=0.02)
    assert np.all(found.stderr < 0.01) and found.n == K


def _levels_data(levels=(1.0, 1.04), seconds=60.0, seed=2):
    rng = np.random.default_rng(seed)
    parts = []
    for g, level in enumerate(levels):
        K = int(seconds * 100)
        t = np.arange(K) * 0.01
        w = np.full((K, 4), 600.0) * (1 + 0.05 * np.sin(0.8 * t))[:, None] + rng.normal(0, 3, (K, 4))
        S = np.sum(w**2, 1)
        yz = level * K_T * S + rng.normal(0, 0.05, K)
        parts.append((np.full(K, g), t, yz, S))
    group, t, yz, S = (np.concatenate(x) for x in zip(*parts))
    return group, t, yz, S


def test_thrust_levels_found_where_recordings_differ_and_not_otherwise():
    group, t, yz, S = _levels_data((1.0, 1.04))
    far = np.ones(len(t), bool)
    lv = thrust_levels(group, t, yz, S, far, ["a", "b"])
    assert lv.differ and lv.level[1] / lv.level[0] == pytest.approx(1.04, rel=2e-3)
    assert lv.spread_percent == pytest.approx(4.0, abs=0.2) and "each gets its own" in lv.why
    group, t, yz, S = _levels_data((1.0, 1.0))
    same = thrust_levels(group, t, yz, S, far, ["a", "b"])
    assert not same.differ and np.all(same.level == 1.0) and "one thrust coefficient" in same.why
    # a recording never far from the surfaces cannot be measured: one thrust coefficient
    lone = thrust_levels(group, t, yz, S, group == 0, ["a", "b"])
    assert not lone.differ and np.isnan(lone.k_T[1])


def _ground_flights(mus=(2.0, 2.0), levels=(1.0, 1.0), seconds=40.0, seed=3, noise=0.03,
                    tops=(1.4, 1.4)) -> GapData:
    """Two recordings of a vehicle climbing and sinking over the floor (rotor plane 0.12-1.5 m), with a
    Cheeseman-Bennett ground effect of ``mus`` and thrust levels ``levels``; motion capture only."""
    rng = np.random.default_rng(seed)
    cols = {k: [] for k in ("group", "t", "y", "R", "w", "v", "d")}
    for g, (mu, level, top) in enumerate(zip(mus, levels, tops)):
        K = int(seconds * 100)
        t = np.arange(K) * 0.01
        d = 0.12 + top * (0.5 - 0.5 * np.cos(2 * np.pi * t / 10.0)) ** 2
        R = quat.to_rotation_matrix(quat.from_euler(0.02 * np.sin(t), 0.02 * np.cos(t), np.zeros(K)))
        w = np.full((K, 6), np.sqrt(MASS * GRAVITY / (6 * K_T))) * (1 + 0.03 * np.sin(1.7 * t))[:, None]
        S = np.sum(w**2, 1)
        thrust = level * K_T * S
        y = thrust[:, None] * R[:, :, 2]
        y[:, 2] += thrust * force_ratio(d, mu, R_ROTOR)
        y += rng.normal(0, noise, y.shape)
        for k, x in zip(cols, (np.full(K, g), t, y, R, w, np.zeros((K, 3)), d)):
            cols[k].append(x)
    c = {k: np.concatenate(v) for k, v in cols.items()}
    K = len(c["t"])
    return GapData(c["group"], c["t"], np.zeros((K, 3)), c["y"], c["R"], c["w"], c["v"], c["d"], np.full(K, np.inf),
                   MASS, R_ROTOR, ["a", "b"], "mocap", imu=np.zeros(K, bool), fits_bias=False)


def test_a_thrust_level_between_recordings_does_not_move_mu():
    data = _ground_flights(levels=(1.0, 1.04), tops=(1.4, 1.0))  # the stronger recording flies lower
    pooled = fit_model(data, {"ground_effect"}).nonlinear["ground_effect"]
    levels = apply_thrust_levels(data)
    assert levels.differ
    own = fit_model(data, {"ground_effect"}).nonlinear["ground_effect"]
    assert own == pytest.approx(2.0, rel=0.03)
    assert abs(pooled - 2.0) > abs(own - 2.0)


def _floor_flights(speed_offset: float, mu: float = 2.0, seconds: float = 40.0, seed: int = 5,
                   top: float = 1.52) -> GapData:
    """Two recordings hovering down to the floor and up (rotor plane 0.12 m to ``top``), thrust 6 % up and down
    as they manoeuvre, the controller easing it near the floor so that the Cheeseman-Bennett lift of ``mu``
    carries the rest; the rotors turn ``speed_offset`` [rad/s] faster than recorded (an idle speed in the
    command map); motion capture only."""
    rng = np.random.default_rng(seed)
    cols = {k: [] for k in ("group", "t", "y", "R", "w", "d")}
    for g in range(2):
        K = int(seconds * 100)
        t = np.arange(K) * 0.01
        d = 0.12 + (top - 0.12) * (0.5 - 0.5 * np.cos(2 * np.pi * t / 10.0 + g)) ** 2
        R = quat.to_rotation_matrix(quat.from_euler(0.02 * np.sin(t), 0.02 * np.cos(t), np.zeros(K)))
        lift = MASS * GRAVITY * (1 + 0.06 * np.sin(1.7 * t))  # N, what the rotors and the floor's lift make
        thrust = lift / (1 + force_ratio(d, mu, R_ROTOR))  # N, the rotors' own
        w_true = np.repeat(np.sqrt(thrust / (6 * K_T))[:, None], 6, axis=1)
        y = thrust[:, None] * R[:, :, 2]
        y[:, 2] += thrust * force_ratio(d, mu, R_ROTOR)
        y += rng.normal(0, 0.03, y.shape)
        for k, x in zip(cols, (np.full(K, g), t, y, R, w_true - speed_offset, d)):
            cols[k].append(x)
    c = {k: np.concatenate(v) for k, v in cols.items()}
    K = len(c["t"])
    return GapData(c["group"], c["t"], np.zeros((K, 3)), c["y"], c["R"], c["w"], np.zeros((K, 3)), c["d"],
                   np.full(K, np.inf), MASS, R_ROTOR, ["a", "b"], "mocap", imu=np.zeros(K, bool), fits_bias=False)


def test_speed_offset_is_read_far_from_surfaces():
    """Known answer: thrust K sum((w + delta)^2) with delta a third of the hover speed, recorded as w,
    thrust 6 % up and down in flight; far from the floor the offset comes back within two of its errors, its
    error a few percent of the hover speed; without an offset none stands out; too few rows: None."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    for delta, seed in ((w_h / 3, 5), (0.0, 6)):
        data = _floor_flights(delta, mu=0.0, seed=seed)
        y_thrust = np.einsum("ki,ki->k", data.y, data.R[:, :, 2])
        cells = offset_cells(data.group, data.d_down, data.d_up, R_ROTOR, reach=1.0)
        found = speed_offset(y_thrust, data.rotor_speeds, cells, data.t)
        assert found.w_hover == pytest.approx(w_h - delta, rel=0.01) and found.rows == np.sum(cells >= 0)
        assert abs(found.delta - delta) < 2 * found.stderr and found.stderr < 0.05 * w_h
        assert (found.z > 10) == (delta > 0) and (found.sse_ratio < 0.5) == (delta > 0)
        assert found.counts == (delta > 0)
    assert speed_offset(y_thrust[:100], data.rotor_speeds[:100], np.zeros(100, int), data.t[:100]) is None
    # an offset must matter as well as stand out: 0.25 % of the hover speed at z 5.6 (an hour of the
    # simulator's own flights) does not count, 3 % at z 3 does, 3 % at z 1.5 does not
    assert not SpeedOffset(1.36, 0.24, 535.0, 60_000, 120, 0.9994).counts
    assert (SpeedOffset(16.0, 5.3, 535.0, 60_000, 120, 0.99).counts
            and not SpeedOffset(16.0, 10.7, 535.0, 1, 1, 1).counts)


def test_offset_cells_hold_one_recording_at_one_height():
    """Cells from six rotor radii up (0.6 m here) in 5 % steps of height, one per recording beyond the reach
    (1.0 m); under six radii of the floor or the ceiling, or in a cell of under 30 rows: left out."""
    d = np.r_[np.full(40, 0.5), np.full(40, 0.62), np.full(40, 0.64), np.full(40, 1.2), np.full(40, 3.0),
              np.full(10, 0.8), np.full(40, 0.7)]
    up = np.r_[np.full(210, np.inf), np.full(40, 0.5)]
    group = np.r_[np.zeros(200, int), np.ones(10, int), np.zeros(40, int)]
    cells = offset_cells(group, d, up, 0.1, reach=1.0)
    assert np.all(cells[:40] == -1) and np.all(cells[200:] == -1)  # under six radii; too few; ceiling near
    assert len(set(cells[40:80])) == 1 and cells[40] == cells[79] and cells[40] != cells[80]  # 0.62 / 0.64 m
    assert cells[120] == cells[160 - 1] and cells[120] != cells[80]  # 1.2 and 3.0 m: beyond reach, one cell
    assert len(np.unique(cells[cells >= 0])) == 3 and cells.max() == 2


def test_the_thrust_map_term_covers_a_ground_effect_read_on_offset_speeds():
    """mu = 2 under rotors a third of the hover speed faster than recorded: fitted on the records mu comes
    out too large (near the floor the rotors slow down, by less in proportion than the records say);
    refitted on the speeds moved by the offset read far from the floor it comes back, and the term, half
    the change, lets the stated error cover the truth. Without an offset there is no term."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    data = _floor_flights(w_h / 3)
    final = fit_model(data, {"ground_effect"})
    found, ends, terms = thrust_map_term(data, final)
    mu = final.nonlinear["ground_effect"]
    moved = fit_model(data.with_speed_offset(found.delta), {"ground_effect"}).nonlinear["ground_effect"]
    assert found.counts and ends == (0.0, found.delta)
    assert abs(mu - 2.0) > 0.1 and moved == pytest.approx(2.0, rel=0.03)
    assert terms["ground_effect"]["mu"] == pytest.approx(abs(moved - mu) / 2, rel=0.02)
    budget = with_systematic(error_budget(data, final, "ground_effect"), "thrust_map", terms["ground_effect"])
    assert budget["mu"]["stderr"] >= budget["mu"]["thrust_map"] and abs(mu - 2.0) <= 2 * budget["mu"]["stderr"]
    clean = _floor_flights(0.0, seed=6)  # no offset: one standard error either side of a reading near none
    found0, ends0, terms0 = thrust_map_term(clean, fit_model(clean, {"ground_effect"}))
    assert found0.z < 2 and ends0 == pytest.approx((found0.delta - found0.stderr, found0.delta + found0.stderr))
    assert terms0["ground_effect"]["mu"] < 0.1 * terms["ground_effect"]["mu"]


def test_an_offset_no_flight_reads_is_left_open_in_the_errors():
    """The same flights kept under six rotor radii (0.12-0.5 m): no row reads the offset, so the errors carry the
    change over the idle speeds left open (none to half the recorded hover speed), which covers the truth, a third
    of it."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    data = _floor_flights(w_h / 4, top=0.5)  # recorded at hover: 3/4 of w_h, so the offset is a third of that
    final = fit_model(data, {"ground_effect"})
    found, ends, terms = thrust_map_term(data, final)
    assert found is None and UNREAD_OFFSET_SPAN[0] <= 1 / 3 <= UNREAD_OFFSET_SPAN[1]
    assert ends[0] == 0.0 and ends[1] == pytest.approx(UNREAD_OFFSET_SPAN[1] * 0.75 * w_h, rel=0.05)
    mu = final.nonlinear["ground_effect"]
    budget = with_systematic(error_budget(data, final, "ground_effect"), "thrust_map", terms["ground_effect"])
    assert abs(mu - 2.0) > 3 * budget["mu"]["sample"]  # the records alone are confidently wrong
    assert abs(mu - 2.0) <= 2 * budget["mu"]["stderr"]
    assert abs(mu - 2.0) <= 2 * budget["mu"]["thrust_map"]  # the term alone covers it


def test_a_law_named_from_the_curve_carries_the_thrust_map_term_too():
    """A law named from the measured curve has the curve's values, which offset speeds bias as well: its
    term is half the change of the law fitted to the curve measured on the moved speeds, which finds the
    truth (mu = 2) again; the stated error then covers it. Without an offset that counts, nothing changes."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    data = _floor_flights(w_h / 3)
    final = fit_model(data, {"ground_effect"})
    _, _, fits = finder_surface_curve(data, final, resample=False)
    mu = fits["ground_effect"].params["mu"]
    entry = {"name": "ground_effect", "params": {"mu": mu}, "named_from": "surface_curve",
             "error_budget": {"mu": {"sample": 0.01, "stderr": 0.01, "limited_by": "sample"}}, "stderr": {"mu": 0.01}}
    found, ends, _ = thrust_map_term(data, final)
    at_ends = curves_at_open_offsets(data, final, {"open_interval_rad_s": list(ends)})
    out = curve_named_thrust_map([copy.deepcopy(entry)], None, at_ends)[0][0]
    moved = data.with_speed_offset(found.delta)
    _, _, moved_fits = finder_surface_curve(moved, fit_model(moved, {"ground_effect"}), resample=False)
    assert moved_fits["ground_effect"].params["mu"] == pytest.approx(2.0, rel=0.05) and abs(mu - 2.0) > 0.2
    assert (out["error_budget"]["mu"]["thrust_map"]
            == pytest.approx(abs(moved_fits["ground_effect"].params["mu"] - mu) / 2))
    assert out["error_budget"]["mu"]["limited_by"] == "thrust_map" and abs(mu - 2.0) <= 2.1 * out["stderr"]["mu"]
    assert curve_named_thrust_map([copy.deepcopy(entry)], None, []) == ([entry], None)
    assert curves_at_open_offsets(data, final, {"open_interval_rad_s": [0.0, 0.0]}) == []


def test_named_values_are_stated_at_the_centre_of_the_offsets_left_open():
    """Where the offset counts but is not decisive, the values are stated halfway to it; where it does not count
    but leaves a wide interval open, at the reading (the interval's centre; 0 lay outside it: Neural-Swarm's 32 g
    take-off, 401 +- 274 rad/s); at 0 where nothing that matters is open, where the reading is decisive (the whole
    analysis moves the speeds) and where there is no reading (no data move the declared speeds)."""
    counts = SpeedOffset(206.0, 61.0, 1900.0, 5000, 20, 0.9)
    assert counts.counts and not counts.decisive and stated_offset(counts, counts.open_interval()) == 103.0
    wide = SpeedOffset(400.9, 273.7, 1900.0, 900, 4, 0.97)
    assert not wide.counts and stated_offset(wide, wide.open_interval()) == pytest.approx(400.9)
    narrow = SpeedOffset(1.36, 0.24, 535.0, 60_000, 120, 0.9994)
    assert stated_offset(narrow, narrow.open_interval()) == 0.0
    decisive = SpeedOffset(48.0, 1.1, 150.0, 5000, 5, 0.28)
    assert decisive.decisive and stated_offset(decisive, decisive.open_interval()) == 0.0
    at_bound = SpeedOffset(1900.0, 0.0, 1900.0, 5000, 5, 0.5, at_bound=True)
    assert at_bound.open_interval()[1] > 0 and stated_offset(at_bound, at_bound.open_interval()) == 0.0
    assert stated_offset(None, (0.0, 800.0)) == 0.0
    assert stated_offset(counts, (float("nan"), float("nan"))) == 0.0


def test_a_value_stated_at_the_centre_of_an_offset_that_counts_is_nearer_the_truth():
    """mu = 2 under rotors a third of the hover speed faster than recorded, the thrust level wandering 2 % as the
    flights go on: the offset reads counting but short of decisive; at the recorded speeds (one end of what it
    leaves open) mu reads far off, at the centre nearer, within the term (both ends' half change). The refit keeps
    the effects chosen and the hover speed; with measured speeds (no thrust map) nothing moves."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    data = _floor_flights(w_h / 3)
    wander = 1.0 + 0.02 * np.sin(2 * np.pi * data.t / 13.0 + data.group)
    data = dataclasses.replace(data, y=data.y * wander[:, None])
    final = fit_model(data, {"ground_effect"})
    thrust_map = thrust_map_term(data, final)
    found, ends, terms = thrust_map
    assert found.counts and not found.decisive and ends == (0.0, found.delta)
    stated, moved, at = at_stated_offset(data, final, thrust_map)
    assert stated == pytest.approx(found.delta / 2) and at.effects == final.effects
    hover = np.median(np.mean(data.rotor_speeds, axis=1))
    assert np.median(np.mean(moved.rotor_speeds, axis=1)) == pytest.approx(hover, rel=0.01)
    mu0, mu = final.nonlinear["ground_effect"], at.nonlinear["ground_effect"]
    assert abs(mu0 - 2.0) > 0.5 and abs(mu - 2.0) < 0.5 * abs(mu0 - 2.0)
    assert abs(mu - 2.0) <= terms["ground_effect"]["mu"]
    assert at_stated_offset(data, final, None) == (0.0, data, final)


def test_speeds_moved_keeping_the_hover_speed_keep_stopped_rotors_stopped():
    """(w + delta) w_h / (w_h + delta): the hover speed stays, 0 stays 0, the rest moves as the affine map says."""
    data = _ground_flights(seed=5)
    data.rotor_speeds[:3] = 0.0
    w_h = float(np.median(data.rotor_speeds[3:]))
    moved = data.with_speed_offset(100.0, w_h)
    np.testing.assert_allclose(moved.rotor_speeds[3:], (data.rotor_speeds[3:] + 100.0) * w_h / (w_h + 100.0))
    assert np.all(moved.rotor_speeds[:3] == 0.0)
    assert np.median(moved.rotor_speeds[3:]) == pytest.approx(w_h)


def test_speeds_moved_by_an_offset_leave_the_rows_they_came_from_alone():
    data = _ground_flights(seed=5)
    S0 = data.S.copy()
    moved = data.with_speed_offset(50.0)
    np.testing.assert_allclose(moved.S, np.sum((data.rotor_speeds + 50.0) ** 2, axis=1))
    np.testing.assert_array_equal(data.S, S0)
    sub = data.subset(data.d_down < 0.5)  # rows of contiguous flights: the lag filters the moved speeds
    np.testing.assert_allclose(sub.with_speed_offset(50.0).contiguous.rotor_speeds, data.rotor_speeds + 50.0)
    assert sub.contiguous is data


def test_thrust_levels_at_matched_heights_where_no_recording_flies_far():
    """Flights that never leave the ground effect's reach (rotor plane 0.12-0.62 m, reach 0.87 m), the
    stronger one lower: the levels come from matched heights, the lift cancels, mu stays right."""
    data = _ground_flights(levels=(1.0, 1.04), tops=(0.5, 0.3))
    levels = apply_thrust_levels(data)
    assert levels.basis == "matched heights" and levels.differ and "matched heights" in levels.why
    assert levels.level[1] / levels.level[0] == pytest.approx(1.04, rel=3e-3)
    assert levels.relative[1] / levels.relative[0] == pytest.approx(1.04, rel=3e-3)
    assert fit_model(data, {"ground_effect"}).nonlinear["ground_effect"] == pytest.approx(2.0, rel=0.05)
    same = apply_thrust_levels(_ground_flights(levels=(1.0, 1.0), tops=(0.5, 0.3)))
    assert same.basis == "matched heights" and not same.differ and np.all(same.level == 1.0)


def _sweeps_on_a_sagging_battery(k_V: float, seed: int = 7):
    """Two 60 s recordings of one vehicle, no level between them, sweeping the rotor plane over 0.12-0.62 m, one in
    its first half (then hovering at the top), the other in its second: commanded speeds whose thrust follows the
    battery's voltage by ``k_V`` [1/V]. The voltage falls 1.2 V over each flight and stands higher where the ground
    effect unloads the rotors (a sag under load); a Cheeseman-Bennett lift of mu = 2. Rows:
    ``(group, t, y_thrust, S, height, voltage_dev)``."""
    rng = np.random.default_rng(seed)
    parts = []
    for g in range(2):
        K = 6000
        t = np.arange(K) * 0.01
        phase = np.clip((t - 30.0 * g) / 30.0, 0.0, 1.0)  # 0 -> 1 over the half it sweeps in
        d = 0.62 - 0.5 * np.sin(np.pi * phase) ** 2 * (np.abs(np.sin(2 * np.pi * 3 * phase)) + 0.2) / 1.2
        S = np.full(K, MASS * GRAVITY / K_T) * (1 + 0.03 * np.sin(1.7 * t)) + rng.normal(0, 1e3, K)
        lift = force_ratio(d, 2.0, R_ROTOR)
        volts = 16.0 - 0.02 * t + 2.0 * lift + rng.normal(0, 0.005, K)
        dv = volts - volts.mean()
        y = K_T * S * (1 + k_V * dv) * (1 + lift) + rng.normal(0, 0.05, K)
        parts.append((np.full(K, g), t, y, S, d, dv))
    return tuple(np.concatenate(x) for x in zip(*parts))


def test_thrust_levels_follow_the_voltage_within_recordings_not_between():
    """Matched heights flown at different battery states (the low bins early in one flight, late in the other) read
    a level between two flights that have none; measured with the thrust taken back to each recording's mean
    voltage, they agree, and the slope is the truth's within 10 % though the voltage is higher near the floor."""
    group, t, y, S, d, dv = _sweeps_on_a_sagging_battery(k_V=0.13)
    none = np.zeros(len(t), bool)
    kappa, kappa_se = level_voltage_slope(group, t, y, S, dv, d, np.ones(len(t), bool))
    assert kappa == pytest.approx(0.13, rel=0.1) and kappa > 10 * kappa_se
    blind = thrust_levels(group, t, y, S, none, ["a", "b"], height=d, matched=~none)
    assert blind.basis == "matched heights" and blind.differ  # 4.6 % apart, read off the voltage
    with_volts = thrust_levels(group, t, y, S, none, ["a", "b"], height=d, matched=~none, voltage_dev=dv)
    assert not with_volts.differ and with_volts.spread_percent < 0.5
    assert "taken back to each recording's mean voltage" in with_volts.why and "per volt" in with_volts.why
    # where the thrust does not follow the voltage, the levels are measured as they were
    group, t, y, S, d, dv = _sweeps_on_a_sagging_battery(k_V=0.0)
    kappa, kappa_se = level_voltage_slope(group, t, y, S, dv, d, np.ones(len(t), bool))
    assert abs(kappa) < 3 * kappa_se
    plain = thrust_levels(group, t, y, S, none, ["a", "b"], height=d, matched=~none)
    same = thrust_levels(group, t, y, S, none, ["a", "b"], height=d, matched=~none, voltage_dev=dv)
    np.testing.assert_array_equal(same.k_T, plain.k_T)
    assert same.why == plain.why and same.differ == plain.differ


def test_matched_height_levels_take_each_bin_to_one_height():
    """Two recordings sweeping different heights (0.07-0.60 and 0.085-0.45 m) in a steep Cheeseman-Bennett lift,
    four wide height bins: within a bin their rows sit at other heights on average and read other lifts. Each
    cell taken to its bin's height, the levels come back within 0.1 % (0.2 % off as the bins' ratios stood)."""
    rng = np.random.default_rng(4)
    for levels in ((1.0, 1.0), (1.0, 1.03)):
        parts = []
        for g, (level, low, high, period) in enumerate(zip(levels, (0.07, 0.085), (0.60, 0.45), (7.0, 11.0))):
            t = np.arange(6000) * 0.01
            d = low + (high - low) * (0.5 - 0.5 * np.cos(2 * np.pi * t / period)) ** 2
            S = np.full(len(t), 1.7e6) * (1 + 0.03 * np.sin(1.3 * t)) + rng.normal(0, 1e3, len(t))
            y = level * K_T * S * (1 + force_ratio(d, 2.0, R_ROTOR)) + rng.normal(0, 0.05, len(t))
            parts.append((np.full(len(t), g), t, y, S, d))
        group, t, y, S, d = (np.concatenate(x) for x in zip(*parts))
        k, se, shared = matched_height_levels(group, t, y, S, d, np.ones(len(t), bool), bins=4)
        assert shared == 4 and k[1] / k[0] == pytest.approx(levels[1], rel=1e-3)
        assert np.all(se / k < 5e-4)


def test_matched_height_levels_need_shared_heights():
    """Two recordings at heights that never overlap cannot be compared: no level measured."""
    data = _ground_flights(levels=(1.0, 1.04), tops=(0.05, 0.05))
    data.d_down = np.where(data.group == 1, data.d_down + 1.0, data.d_down)
    y_thrust = np.einsum("ki,ki->k", data.y, data.R[:, :, 2])
    k, se, shared = matched_height_levels(data.group, data.t, y_thrust, data.S, data.d_down,
                                          np.ones(len(data), bool))
    assert shared == 0 and np.all(np.isnan(k))


def test_honest_errors_cover_the_spread_between_recordings():
    """Two sessions whose ground effect differs (mu 1.6 and 2.4): the sample error is tiny, the stated
    one covers each recording's own fit within about two of it."""
    data = _ground_flights(mus=(1.6, 2.4))
    final = fit_model(data, {"ground_effect"})
    budget = error_budget(data, final, "ground_effect")["mu"]
    se = honest_stderr({"mu": budget})["mu"]
    mu = final.nonlinear["ground_effect"]
    assert budget["sample"] < 0.25 * np.std([1.6, 2.4], ddof=1) and budget["fits"] == 2
    assert budget["limited_by"] == "between_recordings" and se == pytest.approx(np.std([1.6, 2.4], ddof=1), rel=0.1)
    for g, truth in enumerate((1.6, 2.4)):
        alone = fit_model(data.subset(data.group == g), {"ground_effect"}).nonlinear["ground_effect"]
        assert alone == pytest.approx(truth, rel=0.05) and abs(alone - mu) < 2.0 * se
    assert budget["height_reference"] > 0  # a centimetre of height moves mu
    assert HEIGHT_REFERENCE_M == 0.01


def test_a_recording_too_short_to_fit_alone_is_left_out_of_the_spread():
    """Beside two sessions (mu 1.6 and 2.4), a third with 60 rows in flight (a take-off whose rotor speeds
    update at 3 Hz) cannot be analysed alone: its own fit is noise, not a session's spread, and is left out."""
    data = _ground_flights(mus=(1.6, 2.4, 6.0), levels=(1.0, 1.0, 1.0), tops=(1.4, 1.4, 1.4))
    data = data.subset((data.group < 2) | (data.t < 0.6))
    assert np.sum(data.group == 2) == 60 < MIN_ROWS
    final = fit_model(data, {"ground_effect"})
    budget = error_budget(data, final, "ground_effect")["mu"]
    assert budget["fits"] == 2 and budget["recordings_too_short"] == 1
    assert budget["between_recordings"] == pytest.approx(np.std([1.6, 2.4], ddof=1), rel=0.1)
    whole = data.subset(data.group < 2)
    assert "recordings_too_short" not in error_budget(whole, fit_model(whole, {"ground_effect"}), "ground_effect")["mu"]


def _drag_flights(sideways=(True, True, False), k_d=(8.0e-5, 9.0e-5, 8.5e-5), seconds=30.0, seed=7,
                  noise=0.03) -> GapData:
    """Recordings of a hexarotor with rotor drag ``k_d``: those ``sideways`` fly back and forth at up to 2 m/s, the
    others climb and sink in place (a take-off: 2 mm/s sideways); motion capture only."""
    rng = np.random.default_rng(seed)
    cols = {k: [] for k in ("group", "t", "y", "R", "w", "v")}
    for g, (side, kd) in enumerate(zip(sideways, k_d)):
        K = int(seconds * 100)
        t = np.arange(K) * 0.01
        speed = 2.0 if side else 0.002
        v = np.stack([speed * np.sin(2 * np.pi * t / 6.0), 0.5 * speed * np.cos(2 * np.pi * t / 4.0),
                      0.3 * np.sin(2 * np.pi * t / 5.0)], 1)
        R = quat.to_rotation_matrix(quat.from_euler(0.02 * np.sin(t), 0.02 * np.cos(t), np.zeros(K)))
        w = np.full((K, 6), np.sqrt(MASS * GRAVITY / (6 * K_T))) * (1 + 0.03 * np.sin(1.7 * t))[:, None]
        thrust = K_T * np.sum(w**2, 1)
        vB = np.einsum("kji,kj->ki", R, v)
        drag = -kd * np.sum(w, 1)[:, None] * np.einsum("kij,kj->ki", R, vB * np.array([1.0, 1.0, 0.0]))
        y = thrust[:, None] * R[:, :, 2] + drag + rng.normal(0, noise, (K, 3))
        for k, x in zip(cols, (np.full(K, g), t, y, R, w, v)):
            cols[k].append(x)
    c = {k: np.concatenate(x) for k, x in cols.items()}
    K = len(c["t"])
    return GapData(c["group"], c["t"], np.zeros((K, 3)), c["y"], c["R"], c["w"], c["v"], np.full(K, np.inf),
                   np.full(K, np.inf), MASS, R_ROTOR, ["a", "b", "c"][:len(sideways)], "mocap",
                   imu=np.zeros(K, bool), fits_bias=False)


def test_a_recording_that_cannot_test_a_drag_is_left_out_of_the_spread():
    """Two sessions flying sideways (k_d 8 and 9 x 1e-5) and a take-off that barely moves sideways: the take-off's
    own drag fit is noise, not a session's spread; the error covers the two sessions, and with one left the spread
    between blocks stands in."""
    data = _drag_flights()
    final = fit_model(data, {"rotor_drag"})
    testable = lambda d: can_test_alone(d, final, "rotor_drag")  # noqa: E731
    assert [testable(data.subset(data.group == g)) for g in range(3)] == [True, True, False]
    budget = error_budget(data, final, "rotor_drag", can_test=testable)["k_d"]
    assert budget["fits"] == 2 and budget["recordings_cannot_test"] == ["c"]
    assert budget["between_recordings"] == pytest.approx(np.std([8.0e-5, 9.0e-5], ddof=1), rel=0.15)
    _, own_se = fit_model(data.subset(data.group == 2), {"rotor_drag"}).effect_params("rotor_drag")
    assert own_se["k_d"] > 5 * budget["between_recordings"]  # the take-off alone cannot tell the sessions apart
    assert error_budget(data, final, "rotor_drag")["k_d"]["fits"] == 3  # without the test it counted as one
    one = data.subset(data.group != 1)
    alone = error_budget(one, fit_model(one, {"rotor_drag"}), "rotor_drag",
                         can_test=lambda d: can_test_alone(d, final, "rotor_drag"))["k_d"]
    assert "between_recordings" not in alone and np.isfinite(alone["between_blocks"])


def test_the_budgets_of_one_model_share_their_refits():
    """Two budgets of one model (the decision whether the law is pinned, without the height reference, then the
    named effect's) refit each recording and each height shift once, and state what unshared refits state."""
    data = _ground_flights(mus=(1.6, 2.4))
    final = fit_model(data, {"ground_effect"})
    refits = Refits()
    pinned = error_budget(data, final, "ground_effect", height_reference_m=0.0, refits=refits)["mu"]
    assert len(refits) == 2  # each recording alone
    named = error_budget(data, final, "ground_effect", refits=refits)["mu"]
    assert len(refits) == 4  # and the heights moved up and down: the recordings' fits were reused
    assert named == error_budget(data, final, "ground_effect")["mu"]
    assert pinned["between_recordings"] == named["between_recordings"] > 0


def test_one_recording_gets_a_block_jackknife():
    data = _ground_flights(mus=(2.0,), seconds=50.0).subset(np.ones(5000, bool))
    data = data.subset(data.group == 0)
    final = fit_model(data, {"ground_effect"})
    budget = error_budget(data, final, "ground_effect")["mu"]
    assert "between_blocks" in budget and np.isfinite(budget["between_blocks"]) and budget["fits"] == 5
    assert final.nonlinear["ground_effect"] == pytest.approx(2.0, abs=3 * budget["stderr"])


def test_height_uncertainty_sets_the_height_reference_term():
    data = _ground_flights(mus=(2.0, 2.0))
    final = fit_model(data, {"ground_effect"})
    wide = error_budget(data, final, "ground_effect", height_reference_m=0.02)["mu"]["height_reference"]
    narrow = error_budget(data, final, "ground_effect", height_reference_m=0.002)["mu"]["height_reference"]
    assert narrow < 0.2 * wide  # a better known floor and rotor plane, a tighter mu


def test_the_pooled_thrust_coefficient_error_covers_the_recordings_spread():
    """Recordings whose levels agree share one k_T: its stated error is the larger of the sample error and
    the standard deviation of the recordings' own levels (each lands within about two of it); where the
    levels differ each recording has its own, and the one stated for the vehicle covers their spread (a probe's two
    sessions 8 % apart had read k_T +- 0.0094 %)."""
    fit = ModelFit(frozenset(), {}, {"k_T": 1.0e-6}, {"k_T": 1.0e-9}, 0.01)
    data = SimpleNamespace(names=["a", "b", "c"], fits_bias=False, anchored={}, rotor_quantum=0.0)
    k = np.array([0.99e-6, 1.0e-6, 1.02e-6])
    agree = ThrustLevels(k, np.full(3, 2e-9), np.ones(3), False, "agree")
    out = _nominal(data, fit, agree)
    assert out["thrust_coefficient_stderr"] == pytest.approx(np.std(k, ddof=1))
    assert np.all(np.abs(k - 1.0e-6) < 2 * out["thrust_coefficient_stderr"])
    differ = ThrustLevels(k, np.full(3, 2e-9), k / 1.0e-6, True, "differ")
    own = _nominal(data, fit, differ)
    assert own["thrust_coefficient_stderr"] == pytest.approx(np.std(k, ddof=1))
    assert own["thrust_coefficient_per_recording"] == pytest.approx(dict(zip(data.names, k)))
    # each recording's own with its error: the pooled fit's and its level's (a probe's sessions had none)
    assert own["thrust_coefficient_per_recording_stderr"] == pytest.approx(
        {n: kk * np.hypot(1e-3, 2e-9 / kk) for n, kk in zip(data.names, k)})
    # agreeing, each has the pooled value and its stated error
    assert out["thrust_coefficient_per_recording_stderr"] == pytest.approx(
        {n: out["thrust_coefficient_stderr"] for n in data.names})


def test_a_disagreeing_surface_curve_widens_the_stated_error():
    """The finder's mu 3.6 +- 0.64 where the measured curve gives 1.6 (a biased fit): half their difference is
    added in quadrature to the stated error; an agreeing curve's small term leaves the sample term limiting."""
    budget = {"mu": {"sample": 0.49, "height_reference": 0.41, "between_recordings": 0.33, "stderr": 0.64,
                     "limited_by": "sample", "fits": 2}}
    wide = with_curve_check(budget, {"mu": 3.6}, "mu", 1.6)["mu"]
    assert wide["surface_curve"] == pytest.approx(1.0) and wide["stderr"] == pytest.approx(np.hypot(0.64, 1.0))
    assert wide["limited_by"] == "surface_curve" and budget["mu"]["stderr"] == 0.64  # the input is left alone
    close = with_curve_check(budget, {"mu": 3.6}, "mu", 3.4)["mu"]
    assert close["surface_curve"] == pytest.approx(0.1) and close["stderr"] == pytest.approx(np.hypot(0.64, 0.1))
    assert close["limited_by"] == "sample"


def test_rotor_timing_term_is_half_the_change_across_the_timing_interval():
    """mu 1.8 and 2.2 at the two ends of the rotor stream's timing interval: the term is 0.2, added in
    quadrature to the stated 0.11, and limits it; a fit that failed at either end leaves the term unknown (nan), never
    a confident zero, and the stated error as it was."""
    budget = {"mu": {"sample": 0.05, "height_reference": 0.1, "between_recordings": 0.08, "stderr": 0.11,
                     "limited_by": "height_reference", "fits": 2}}
    term = timing_term({"mu": 1.8}, {"mu": 2.2}, ("mu",))
    assert term == {"mu": pytest.approx(0.2)}
    out = with_systematic(budget, "rotor_timing", term)["mu"]
    assert out["stderr"] == pytest.approx(np.hypot(0.11, 0.2)) and out["limited_by"] == "rotor_timing"
    unknown = with_systematic(budget, "rotor_timing", timing_term(None, {"mu": 2.2}, ("mu",)))["mu"]
    assert np.isnan(unknown["rotor_timing"]) and unknown["stderr"] == 0.11


@pytest.mark.parametrize("found, interval", [
    ({"lag_s": 0.06, "stderr_s": 0.004, "resolvable": True, "applied": True}, (-0.004, 0.004)),
    ({"lag_s": 0.003, "stderr_s": 0.01, "resolvable": True, "applied": False}, (0.0, 0.013)),
    ({"lag_s": 0.002, "stderr_s": 0.001, "resolvable": True, "applied": False}, (0.0, MIN_DELAY_S)),
    ({"lag_s": 0.095, "stderr_s": 0.036, "resolvable": False, "applied": False}, (0.0, TELEMETRY_DELAY_MAX_S)),
    ({"lag_s": float("nan"), "stderr_s": float("nan"), "resolvable": False, "applied": False},
     (0.0, TELEMETRY_DELAY_MAX_S)),
    ({"lag_s": 0.003, "stderr_s": 0.004, "resolvable": True, "applied": True}, (-0.003, 0.004)),
])
def test_timing_interval_covers_what_is_left_uncertain_of_a_delay(found, interval):
    """One standard error either side of a delay taken out (never before a zero delay), up to one beyond a
    timed delay too small to take out, and 0 to 80 ms (``recordings.md``) where none could be timed."""
    assert timing_interval(found) == pytest.approx(interval)


def test_a_law_whose_shape_misses_the_curve_still_carries_the_curve_term():
    """The named law's value (mu 5.0, fitted on every row) against the same law fitted to a measured curve
    whose shape it does not fit (mu 7.0, chi^2/dof 10): the two weigh the heights differently, and the stated
    error carries half their difference in quadrature; a law without a finite curve value is left as it was."""
    budget = {"mu": {"sample": 0.3, "height_reference": 0.5, "stderr": 0.58, "limited_by": "sample", "fits": 1}}
    effects = [{"name": "ground_effect", "params": {"mu": 5.0}, "stderr": {"mu": 0.58}, "error_budget": budget}]
    misfit = SimpleNamespace(law_fits=False, value=7.0, param="mu")
    out = cross_checked(copy.deepcopy(effects), {"ground_effect": misfit})[0]
    assert out["error_budget"]["mu"]["surface_curve"] == pytest.approx(1.0)
    assert out["stderr"]["mu"] == pytest.approx(np.hypot(0.58, 1.0))
    assert out["error_budget"]["mu"]["limited_by"] == "surface_curve"
    none = SimpleNamespace(law_fits=False, value=float("nan"), param="mu")
    assert cross_checked(copy.deepcopy(effects), {"ground_effect": none})[0] == effects[0]


def test_command_sampling_term_is_a_quarter_of_the_slowest_hold_period():
    assert command_sampling_term([0.01, 0.0125])["tau"] == pytest.approx(0.003125)
    assert command_sampling_term([1 / 3])["tau"] == pytest.approx(1 / 12)  # ESC telemetry at 3 Hz: no lag to pin
    assert np.isnan(command_sampling_term([])["tau"]) and np.isnan(command_sampling_term([0.0, np.nan])["tau"])
    budget = {"tau": {"sample": 1e-4, "stderr": 1e-4, "limited_by": "sample"}}
    out = with_systematic(budget, "command_sampling", command_sampling_term([0.01]))
    assert (out["tau"]["stderr"] == pytest.approx(np.hypot(1e-4, 0.0025))
            and out["tau"]["limited_by"] == "command_sampling")


def test_an_offset_is_decisive_from_ten_errors():
    # an idle speed in a command map read 44 errors from zero is; the Neural-Swarm walks' 3-7 errors are not
    assert SpeedOffset(48.0, 1.1, 150.0, 5000, 5, 0.28).decisive
    walks = SpeedOffset(30.0, 4.5, 600.0, 5000, 5, 0.8)
    assert walks.counts and not walks.decisive
    assert not SpeedOffset(1.36, 0.01, 535.0, 60_000, 120, 0.9994).decisive  # stands out, does not matter


def test_an_offset_at_an_end_of_the_range_searched_is_no_reading():
    """Thrust per recorded speed squared that an offset of twice the hover speed would steady, beyond the range
    searched (-50 to +100 %): the least residual lies at its end, with no spread over the jackknife; that is no
    reading (it had been taken as infinitely many errors from zero, and applied), and neither is an error of 0."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    data = _floor_flights(2.0 * w_h, mu=0.0, seed=7)
    y_thrust = np.einsum("ki,ki->k", data.y, data.R[:, :, 2])
    cells = offset_cells(data.group, data.d_down, data.d_up, R_ROTOR, reach=1.0)
    found = speed_offset(y_thrust, data.rotor_speeds, cells, data.t)
    assert found.at_bound and found.delta == pytest.approx(found.w_hover)  # +100 % of the hover speed
    assert np.isnan(found.z) and not found.counts and not found.decisive
    assert not SpeedOffset(48.0, 0.0, 150.0, 5000, 5, 0.28).counts  # no spread: no z


@dataclasses.dataclass
class _RotorsOnly:
    """A recording's rotor stream alone (what :func:`rotor_speeds_moved` reads)."""

    rotors: Rotors


def test_rotor_speeds_moved_keep_stopped_rotors_stopped():
    speeds = np.array([[0.0, 100.0], [30.0, 0.0], [150.0, 160.0]])
    rec = _RotorsOnly(Rotors(t_ns=np.arange(3), speeds=speeds.copy()))
    # hover 150 rad/s kept: (w + 50) * 150 / 200; a negative offset: (w - 40) * 150 / 110, never under 0
    np.testing.assert_allclose(rotor_speeds_moved(rec, 50.0, 150.0).rotors.speeds,
                               [[0, 112.5], [60, 0], [150, 157.5]])
    np.testing.assert_allclose(rotor_speeds_moved(rec, -40.0, 150.0).rotors.speeds,
                               [[0, 60 * 150 / 110], [0, 0], [150, 120 * 150 / 110]])
    np.testing.assert_array_equal(rec.rotors.speeds, speeds)  # the recording itself is left alone


def test_a_report_read_on_moved_speeds_carries_the_recorded_reading():
    budget = {"tau": {"sample": 0.001, "stderr": 0.001, "limited_by": "sample"}}
    recorded = {"effects": [{"name": "motor_lag", "params": {"tau": 0.054}}],
                "nominal": {"rotor_speed_offset": {"delta_rad_s": 48.0, "stderr_rad_s": 1.1, "z": 48.0 / 1.1,
                                                   "share_of_hover_speed": 0.32, "hover_speed_rad_s": 150.0,
                                                   "decisive": True, "note": "x"}}}
    moved = {"effects": [{"name": "motor_lag", "params": {"tau": 0.038}, "stderr": {"tau": 0.001},
                          "error_budget": copy.deepcopy(budget)},
                         {"name": "ground_effect", "params": {"mu": 2.6}, "stderr": {"mu": 0.3},
                          "error_budget": {"mu": {"sample": 0.3, "stderr": 0.3, "limited_by": "sample"}}}],
             "nominal": {"rotor_speed_offset": None}}
    out = read_on_moved_speeds(recorded, moved)
    lag, ground = out["effects"]
    assert lag["error_budget"]["tau"]["speed_offset"] == pytest.approx(0.008)
    assert lag["stderr"]["tau"] == pytest.approx(np.hypot(0.001, 0.008)) and lag["error_budget"]["tau"][
        "limited_by"] == "speed_offset"
    assert np.isnan(ground["error_budget"]["mu"]["speed_offset"]) and ground["stderr"]["mu"] == 0.3
    offset = out["nominal"]["rotor_speed_offset"]
    assert offset["applied"] and offset["after"] is None and offset["named_on_recorded_speeds"] == recorded["effects"]
    assert "44 errors from zero" in offset["note"] and "it named motor_lag (tau = 0.054)" in offset["note"]
    assert offset["delta_rad_s"] == 48.0 and offset["stderr_rad_s"] == 1.1 and offset["moves_rad_s"] == [48.0]
    # a surface law the recorded speeds did not name (Cheeseman-Bennett there, the exponential law on the moved
    # speeds): its reading on the recorded speeds is its fit to their measured curve
    recorded["effects"] = [{"name": "ground_effect", "params": {"mu": 8.7}}]
    recorded["surface_curve"] = {"law": "ground_effect", "params": {"mu": 8.2}, "alternatives": [
        {"law": "ground_effect_exponential", "params": {"A": 0.49, "lam": 1.7}},
        {"law": "ground_effect_multirotor", "params": {"K_b": 3.1}}]}
    moved = {"effects": [{"name": "ground_effect_exponential", "params": {"A": 0.25, "lam": 2.4},
                          "stderr": {"A": 0.05, "lam": 0.2}, "named_from": "surface_curve",
                          "error_budget": {"A": {"sample": 0.05, "stderr": 0.05, "limited_by": "sample"},
                                           "lam": {"sample": 0.2, "stderr": 0.2, "limited_by": "sample"}}},
                         {"name": "ground_effect", "params": {"mu": 7.7}, "stderr": {"mu": 3.5},
                          "error_budget": {"mu": {"sample": 3.5, "stderr": 3.5, "limited_by": "sample"}}}],
             "nominal": {"rotor_speed_offset": None}}
    exp, cb = read_on_moved_speeds(recorded, moved)["effects"]
    assert exp["error_budget"]["A"]["speed_offset"] == pytest.approx(0.12)
    assert exp["error_budget"]["lam"]["speed_offset"] == pytest.approx(0.35)
    assert exp["stderr"]["A"] == pytest.approx(np.hypot(0.05, 0.12))
    assert cb["error_budget"]["mu"]["speed_offset"] == pytest.approx(0.5)  # the named value before the curve's


def test_moves_of_the_speeds_compose_into_one_offset():
    """Known answer: moving by 50 (hover 150 kept) and the moved speeds by -10 is one move by 50 - 10 * 200 / 150."""
    w = np.array([[0.0, 60.0], [150.0, 170.0]])
    rec = _RotorsOnly(Rotors(t_ns=np.arange(2), speeds=w.copy()))
    total = composed_offset(50.0, 150.0, -10.0)
    assert total == pytest.approx(50.0 - 10.0 * 200.0 / 150.0)
    twice = rotor_speeds_moved(rotor_speeds_moved(rec, 50.0, 150.0), -10.0, 150.0).rotors.speeds
    np.testing.assert_allclose(twice, rotor_speeds_moved(rec, total, 150.0).rotors.speeds)


def test_an_offset_applied_twice_states_the_last_reading_and_what_it_still_reads():
    """The report of the last of two moves states the last offset applied, with an error that carries what the
    moved speeds still read (in the records' units), and the first reading apart."""
    recorded = {"effects": [],
                "nominal": {"rotor_speed_offset": {"delta_rad_s": 724.0, "stderr_rad_s": 38.0, "z": 19.0,
                                                   "share_of_hover_speed": 0.44, "hover_speed_rad_s": 1650.0,
                                                   "decisive": True, "note": "x"}}}
    after = {"delta_rad_s": -28.0, "stderr_rad_s": 5.0, "counts": False, "note": "y"}
    moved = {"effects": [], "nominal": {"rotor_speed_offset": after}}
    offset = read_on_moved_speeds(recorded, moved, [724.0, 619.0])["nominal"]["rotor_speed_offset"]
    assert offset["delta_rad_s"] == 619.0 and offset["moves_rad_s"] == [724.0, 619.0]
    assert offset["stderr_rad_s"] == pytest.approx(np.hypot(28.0, 5.0) * (1650.0 + 619.0) / 1650.0)
    assert offset["read_on_recorded_speeds"] == {"delta_rad_s": 724.0, "stderr_rad_s": 38.0, "z": 19.0}
    assert "ran 2 times, on the speeds moved by 724, then 619 rad/s" in offset["note"]


@pytest.mark.slow
def test_an_idle_speed_in_the_command_map_is_read_and_the_lag_found_again(tmp_path):
    """Two simulated 50 g quadrotor flights whose recorded speeds are commands scaled at hover while the motors
    idle at a quarter of the hover speed, with a 30 ms lag: the offset is decisive, the analysis runs on the
    moved speeds, and the lag comes back within two stated errors (read on the records it had been 54 ms)."""
    paths = []
    for k, level in enumerate(("1.0", "0.97")):
        path = tmp_path / f"f{k}"
        assert main(["generate", "flight", "--vehicle", "quad", "--effects", "motor_lag:tau=0.03", "--duration", "60",
                     "--kind", "low_passes", "--seed", str(61 + k), "--out", str(path), "--motor-commands",
                     "--ground-contact-s", "2", "--rate-hz", "100", "--thrust-level", level]) == 0
        paths.append(path)
    report, _ = analyse([read_recording(p) for p in paths], {})
    offset = report["nominal"]["rotor_speed_offset"]
    assert offset["applied"] and offset["decisive"] and offset["delta_rad_s"] / offset["stderr_rad_s"] >= 10
    named = {e["name"]: e for e in report["effects"]}
    assert "ground_effect" not in named and "motor_lag" in named
    tau, se = named["motor_lag"]["params"]["tau"], named["motor_lag"]["stderr"]["tau"]
    assert abs(tau - 0.03) <= 2 * se and "speed_offset" in named["motor_lag"]["error_budget"]["tau"]


def test_speed_offset_read_with_the_battery_voltage():
    """Known answer: thrust K (1 + k_V (V - V_mean)) sum((w + delta)^2), the voltage sagging under load (thrust up,
    voltage down) and draining: read alone, the offset takes the sag (far from the truth, many errors off); read
    with the voltage, it comes back within 3 % and three of its errors, k_V V near 2; with no voltage it is as
    before."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    delta, k_V, v_mean = w_h / 3, 2.0 / 15.5, 15.5
    data = _floor_flights(delta, mu=0.0, seed=5)
    y = np.einsum("ki,ki->k", data.y, data.R[:, :, 2])
    true = np.sum((data.rotor_speeds + delta) ** 2, axis=1)  # the true thrust's shape (the sag follows it)
    load = true / np.mean(true) - 1.0
    dv = -3.0 * load - 0.004 * (data.t - np.mean(data.t))  # V: 3 V per unit of relative thrust, 0.24 V a minute
    y_v = y * (1.0 + k_V * dv)
    cells = offset_cells(data.group, data.d_down, data.d_up, R_ROTOR, reach=1.0)
    alone = speed_offset(y_v, data.rotor_speeds, cells, data.t)
    assert abs(alone.delta - delta) > 4 * alone.stderr
    both = speed_offset(y_v, data.rotor_speeds, cells, data.t, voltage_dev=dv, voltage_mean=v_mean)
    assert abs(both.delta - delta) < min(3 * both.stderr, 0.03 * delta)
    assert both.k_V * v_mean == pytest.approx(2.0, abs=0.1)
    plain = speed_offset(y, data.rotor_speeds, cells, data.t, voltage_dev=np.zeros(len(y)), voltage_mean=v_mean)
    before = speed_offset(y, data.rotor_speeds, cells, data.t)
    assert plain.delta == pytest.approx(before.delta, rel=1e-9) and plain.k_V == 0.0


def test_speed_offset_with_a_noisy_voltage_carries_the_voltage_noise_term():
    """The same known answer with the voltage read through white noise of 30 mV (its sag under load 3 V per unit of
    relative thrust, 0.13 V rms): the noise pulls the slope read towards 0 (k_V V 1.4 for 2) and the offset away from
    the truth, 5 jackknife errors; given the noise's variance, the reading's error carries the voltage noise term,
    which covers the truth, and the slope read with the noise taken into account is the true one. Noise of
    variance 0 changes nothing."""
    w_h = np.sqrt(MASS * GRAVITY / (6 * K_T))
    delta, k_V, v_mean = w_h / 3, 2.0 / 15.5, 15.5
    data = _floor_flights(delta, mu=0.0, seed=5)
    y = np.einsum("ki,ki->k", data.y, data.R[:, :, 2])
    true = np.sum((data.rotor_speeds + delta) ** 2, axis=1)
    dv = -3.0 * (true / np.mean(true) - 1.0) - 0.004 * (data.t - np.mean(data.t))
    y_v = y * (1.0 + k_V * dv)
    noisy = dv + np.random.default_rng(8).normal(0.0, 0.03, len(dv))
    cells = offset_cells(data.group, data.d_down, data.d_up, R_ROTOR, reach=1.0)
    read = speed_offset(y_v, data.rotor_speeds, cells, data.t, voltage_dev=noisy, voltage_mean=v_mean)
    assert abs(read.delta - delta) > 3 * read.stderr and read.voltage_noise == 0.0
    var = np.full(len(dv), 0.03**2)
    honest = speed_offset(y_v, data.rotor_speeds, cells, data.t, voltage_dev=noisy, voltage_mean=v_mean,
                          voltage_var=var)
    assert honest.delta == read.delta and honest.k_V == read.k_V  # the reading stays; its error grows
    assert honest.stderr == pytest.approx(np.hypot(read.stderr, honest.voltage_noise))
    assert abs(honest.delta - delta) < 2 * honest.stderr
    assert honest.k_V_noise_free * v_mean == pytest.approx(2.0, abs=0.3) and read.k_V * v_mean < 1.7
    quiet = speed_offset(y_v, data.rotor_speeds, cells, data.t, voltage_dev=noisy, voltage_mean=v_mean,
                         voltage_var=np.zeros(len(dv)))
    assert (quiet.delta, quiet.stderr, quiet.k_V, quiet.voltage_noise) == (read.delta, read.stderr, read.k_V, 0.0)
    assert np.isnan(quiet.k_V_noise_free)


def test_a_thrust_coefficient_beside_an_undecided_thrust_law_states_what_the_law_would_take():
    """Flights that stay 12-17 cm over the floor (all within the ground effect, mu = 2): fitted without the law,
    k_T holds the lift, several times its sample error off the truth. Beside a surface law left undecided its
    error is how far it moves with the law fitted, which covers the truth."""
    data = _ground_flights(tops=(0.05, 0.05))
    final = fit_model(data, set())
    nominal = _nominal(data, final, apply_thrust_levels(data), ["ground_effect"])
    terms = nominal["thrust_coefficient_stderr_terms"]
    with_law = fit_model(data, {"ground_effect"}, with_stderr=False).coef["k_T"]
    assert terms["undecided_thrust_law"] == pytest.approx(abs(with_law - final.coef["k_T"]))
    off = abs(nominal["thrust_coefficient"] - K_T)
    assert off > 5 * terms["sample"]  # the sample error alone was far from covering it
    assert nominal["thrust_coefficient_stderr"] == terms["undecided_thrust_law"] and off < 2 * terms[
        "undecided_thrust_law"]
    assert "undecided_thrust_law" not in _nominal(data, final, apply_thrust_levels(data))[
        "thrust_coefficient_stderr_terms"]


def test_laws_a_shape_left_open_widen_the_thrust_coefficient_as_an_undecided_one_does():
    """The thrust coefficient's error covers what it moves by with each law ``ambiguous`` leaves out of the model:
    the law undecided beside the thrust coefficient, and both laws of a surface effect whose shape is left open
    (the lift is there, only its law is not named); a push left between wind and a tilt does not scale the
    thrust."""
    ambiguous = [{"candidates": ["battery_sag", "thrust_coefficient"]},
                 {"candidates": ["ground_effect", "ground_effect_exponential"], "lift_at_lowest_heights": {}},
                 {"candidates": ["wind", "thrust_axis_tilt"]}]
    assert _thrust_laws_left_open(ambiguous) == ["battery_sag", "ground_effect", "ground_effect_exponential"]
    assert _thrust_laws_left_open([]) == []
    data = _ground_flights(tops=(0.05, 0.05))
    final = fit_model(data, set())
    open_shape = _nominal(data, final, apply_thrust_levels(data), _thrust_laws_left_open(ambiguous[1:2]))
    moves = [abs(fit_model(data, {law}, with_stderr=False).coef["k_T"] - final.coef["k_T"])
             for law in ("ground_effect", "ground_effect_exponential")]
    assert open_shape["thrust_coefficient_stderr_terms"]["undecided_thrust_law"] == pytest.approx(max(moves))
    assert abs(open_shape["thrust_coefficient"] - K_T) < 2 * open_shape["thrust_coefficient_stderr"]
