"""Streams a logger writes faster than they update are read on their updates (``recordings.md``); values
that merely repeat at their resolution are not (sysid/flight_data.py)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from uavturb.gap import locate
from uavturb.gap.design import gap_data
from uavturb.io.recording import GroundTruth, Rotors
from uavturb.numerics.stream_updates import read_at_crossings, staggered, update_mask
from uavturb.physics.effects import parse_effects
from uavturb.physics.vehicle import HEXAROTOR
from uavturb.sim.flights.sensors import SensorNoise
from uavturb.sim.flights.simulate import simulate_flight
from uavturb.sim.core.signals import Constant, Reference, Sines
from uavturb.sysid.flight_data import flight_data, held_updates, rotor_hold_s, rotor_repeats
from uavturb.sysid.streams import needed_rate_hz, slow_for, stream_updates


def _bobbing():
    ref = Reference(Constant(0.0), Constant(0.0), Sines((1.5, 0.3), (0.0, 1.5), (1.5708, 0.0)), Constant(0.0), 12.0,
                    "vertical bobbing")
    rec, truth = simulate_flight(HEXAROTOR, ref, effects=parse_effects("none"), noise=SensorNoise.none(), seed=1)
    return dataclasses.replace(rec, imu=None), truth


def _hold(gt: GroundTruth, every: int) -> GroundTruth:
    """Each value repeated for ``every`` rows (a 200 Hz log of a 200/every Hz estimate)."""
    src = (np.arange(len(gt.t_ns)) // every) * every
    return GroundTruth(gt.t_ns, gt.p[src], gt.q[src], gt.v[src], gt.b_w[src], gt.b_a[src])


def test_held_positions_are_read_on_their_updates():
    rec, truth = _bobbing()
    held = dataclasses.replace(rec, ground_truth=_hold(rec.ground_truth, 20))  # 10 Hz in 200 Hz rows
    gt, _ = held_updates(held)
    assert len(gt.t_ns) == len(rec.ground_truth.t_ns) // 20 + 1  # the updates and the last row
    fd = flight_data(held, window_s=0.3)
    inner = (fd.t > 2.0) & (fd.t < 10.0)
    a_true = np.interp(fd.t, truth.t, np.gradient(truth.x[:, 9], truth.t))  # vertical acceleration [m/s^2]
    err = np.sqrt(np.mean((fd.dv[inner, 2] - a_true[inner]) ** 2))
    assert err < 0.15 * np.std(a_true[inner])
    # differentiating the staircase itself would be far off
    naive = np.gradient(held.ground_truth.v[:, 2], held.ground_truth.t_ns * 1e-9)
    assert np.sqrt(np.mean(naive**2)) > 2 * np.std(a_true[inner])


def test_values_repeated_by_rounding_are_not_a_held_stream():
    rec, _ = _bobbing()
    gt = rec.ground_truth
    rounded = GroundTruth(gt.t_ns, np.round(gt.p, 2), gt.q, np.round(gt.v, 1), gt.b_w, gt.b_a)  # cm, 0.1 m/s
    out, rotors = held_updates(dataclasses.replace(rec, ground_truth=rounded))
    assert out is rounded and rotors is rec.rotors


def test_the_residual_noise_of_a_slow_stream_is_read_between_its_updates():
    """A residual whose stream updates at 5 Hz, interpolated into 25 Hz rows: neighbouring rows share their
    updates, so first differences say the noise is a third of what it is; differences between rows an
    update apart recover it, and the located segments' window counts updates, not rows."""
    rng = np.random.default_rng(4)
    sigma = 0.05  # N per update
    t_u = np.arange(0.0, 120.0, 0.2)  # s, updates at 5 Hz
    t = np.arange(0.0, 119.8, 0.04)  # s, rows at 25 Hz
    r = np.column_stack([np.interp(t, t_u, rng.normal(0, sigma, len(t_u))) for _ in range(3)])
    data = SimpleNamespace(t=t, group=np.zeros(len(t), int))
    naive = locate.residual_noise(data, r)
    held = locate.residual_noise(data, r, update_step_s=0.2)
    assert np.all(naive < 0.5 * sigma)
    np.testing.assert_allclose(held, sigma, rtol=0.15)
    rows, draws = locate.window_rows(data, 0.5)
    assert rows == draws and 12 <= rows <= 13
    assert locate.window_rows(data, 0.5, update_step_s=0.2) == (rows, 2)


def test_a_held_rotor_stream_is_fitted_on_its_updates_only():
    """Rotor speeds held at 3.3 Hz: the rows nearest their updates are marked fresh, the gap finder fits on
    those alone (the interpolated rows between them miss the thrust), and keeps every row in flight for
    sums such as thrust levels."""
    rec, truth = _bobbing()
    every = 60  # 200 Hz rows of a 3.3 Hz telemetry
    src = (np.arange(len(rec.rotors.t_ns)) // every) * every
    held = dataclasses.replace(rec, rotors=Rotors(rec.rotors.t_ns, rec.rotors.speeds[src]))
    fd = flight_data(held, window_s=0.3)
    assert flight_data(rec, window_s=0.3).rotor_fresh is None
    updates = np.flatnonzero(fd.rotor_fresh)
    assert len(updates) == len(rec.rotors.t_ns) // every  # every update but the stream's closing row
    np.testing.assert_array_equal(fd.t_ns[updates], rec.rotors.t_ns[::every][:len(updates)])
    # at the updates the rotor speeds are the measured ones; between them, interpolated, they are off
    S_true = np.interp(fd.t, truth.t, np.sum(truth.rotor_speeds**2, axis=1))
    S = np.sum(fd.rotor_speeds**2, axis=1)
    between = ~fd.rotor_fresh & (fd.t > 1.0) & (fd.t < 11.0)
    fresh = fd.rotor_fresh & (fd.t > 1.0) & (fd.t < 11.0)
    assert np.sqrt(np.mean((S - S_true)[fresh] ** 2)) < 0.05 * np.sqrt(np.mean((S - S_true)[between] ** 2))
    data = gap_data([fd], HEXAROTOR.mass, HEXAROTOR.rotor_radius, k_T_guess=HEXAROTOR.thrust_coefficient)
    # the fit's rows are the updates in flight (single rows, not 25 Hz block means); the dense rows all of it
    assert 30 <= len(data) <= len(updates) and data.dense is not None and len(data.dense) > 5 * len(data)
    assert set(np.round(data.t, 9)) <= set(np.round(fd.t[fd.rotor_fresh], 9))


def _staggered(rotors: Rotors, every: int) -> Rotors:
    """Each rotor's speed held for ``every`` rows, rotor ``c`` updating ``c * every / n`` rows after rotor 0
    (round-robin ESC telemetry: one motor reported at a time)."""
    n = rotors.speeds.shape[1]
    rows = np.arange(len(rotors.t_ns))
    cols = [np.maximum((rows - c * every // n) // every * every + c * every // n, 0) for c in range(n)]
    return Rotors(rotors.t_ns, np.column_stack([rotors.speeds[k, c] for c, k in enumerate(cols)]))


def test_rotor_speeds_reported_one_esc_at_a_time_are_read_column_by_column():
    """Six rotors each updating at 3.3 Hz, staggered: the stream changes in some column at 20 Hz, but each
    column holds its value for 0.3 s. Interpolated column by column between its own updates, the thrust
    at the rows where some column changed is as close to the truth as a synchronous 3.3 Hz stream's at its
    updates, and far closer than the staircase the rows hold."""
    rec, truth = _bobbing()
    every = 60  # 200 Hz rows of a 3.3 Hz telemetry
    stag = dataclasses.replace(rec, rotors=_staggered(rec.rotors, every))
    assert staggered(stag.rotors.speeds) and not staggered(rec.rotors.speeds)
    s = stream_updates("rotors0", stag.rotors.t_ns, stag.rotors.speeds)
    assert s.staggered and s.update_rate_hz == pytest.approx(200 / every, rel=0.02)
    assert s.any_column_rate_hz == pytest.approx(6 * 200 / every, rel=0.02)
    assert s.describe().startswith(f"rotors0: {len(rec.rotors.t_ns)} rows at 200 Hz, each column updating on its own "
                                   "at 3.3 Hz, staggered")
    _, rotors = held_updates(stag)
    assert len(rotors.t_ns) == pytest.approx(6 * len(rec.rotors.t_ns) / every, abs=7)
    S_true = np.interp(rotors.t_ns * 1e-9, truth.t + rec.t0_ns * 1e-9, np.sum(truth.rotor_speeds**2, axis=1))
    inner = (rotors.t_ns - rec.t0_ns > 1e9) & (rotors.t_ns - rec.t0_ns < 11e9)
    read = np.sum(rotors.speeds**2, axis=1)
    held = np.sum(stag.rotors.speeds[np.searchsorted(stag.rotors.t_ns, rotors.t_ns)] ** 2, axis=1)
    err_read = np.sqrt(np.mean((read - S_true)[inner] ** 2))
    assert err_read < 0.3 * np.sqrt(np.mean((held - S_true)[inner] ** 2))


def test_a_quantised_stream_whose_columns_change_at_random_is_not_staggered():
    """A position logged in millimetres at rest, or rotor speeds rounded to 1 rad/s in a hover: the columns
    change one at a time but at random intervals, which is no round-robin telemetry."""
    rng = np.random.default_rng(0)
    at_rest = np.round(np.array([0.1, -0.2, 0.05]) + rng.normal(0, 3e-4, (3000, 3)), 3)
    hover = np.round(600 + rng.normal(0, 0.3, (4000, 4)))
    assert not staggered(at_rest) and not staggered(hover)
    assert not stream_updates("state", np.arange(3000) * 10_000_000, at_rest).staggered
    # speeds that move (so that every update shows) read round-robin, each held 40 rows, one rotor after another
    rows = np.arange(4000)
    moving = hover + rows[:, None] / 40
    held = np.column_stack([moving[np.maximum((rows - 10 * c) // 40 * 40 + 10 * c, 0), c] for c in range(4)])
    assert staggered(held) and not staggered(moving)


def test_a_flight_with_no_row_in_the_air_gives_empty_gap_data():
    """Every row excluded (a recording that rests on its gear throughout): no rows, no error deep in the block
    means (the finder then says 'only 0 samples in flight' in one line)."""
    rec, _ = _bobbing()
    fd = flight_data(rec, window_s=0.3)
    data = gap_data([fd], HEXAROTOR.mass, HEXAROTOR.rotor_radius, k_T_guess=HEXAROTOR.thrust_coefficient,
                    exclude=[np.ones(len(fd), bool)])
    assert len(data) == 0 and data.dense is None


def test_gap_data_releasing_its_flights_builds_the_same_rows():
    """``release`` frees each flight as it is read (memory): the rows are the same, the list holds None."""
    rec, _ = _bobbing()
    fds = [flight_data(rec, window_s=0.3), flight_data(rec, window_s=0.3)]
    kept = gap_data(list(fds), HEXAROTOR.mass, HEXAROTOR.rotor_radius, k_T_guess=HEXAROTOR.thrust_coefficient)
    released = gap_data(fds, HEXAROTOR.mass, HEXAROTOR.rotor_radius, k_T_guess=HEXAROTOR.thrust_coefficient,
                        release=True)
    assert fds == [None, None]
    assert released.names == kept.names == [rec.name, rec.name] and len(released) == len(kept) > 100
    for name in ("group", "t", "p", "y", "R", "rotor_speeds", "v", "d_down", "d_up"):
        np.testing.assert_array_equal(getattr(released, name), getattr(kept, name))
    np.testing.assert_array_equal(released.S_lag(0.03), kept.S_lag(0.03))


def test_gap_data_lets_go_of_what_its_rows_no_longer_read_of_the_contiguous_flights():
    """Once the rows are built, the contiguous flights keep what is read of them: the motor lag's times, recordings
    and rotor speeds, and the simulator's own effects' attitudes, velocities and heights unless no effect is
    simulated (``sim_forces=False``). The rows, and the lagged sums on moved speeds, are the same either way."""
    rec, _ = _bobbing()
    fds = [flight_data(rec, window_s=0.3), flight_data(rec, window_s=0.3)]
    sim = gap_data(list(fds), HEXAROTOR.mass, HEXAROTOR.rotor_radius, k_T_guess=HEXAROTOR.thrust_coefficient)
    bare = gap_data(fds, HEXAROTOR.mass, HEXAROTOR.rotor_radius, k_T_guess=HEXAROTOR.thrust_coefficient,
                    sim_forces=False)
    assert bare.block_of is not None and len(bare) == len(sim) > 100  # 200 Hz samples in 25 Hz block means
    for name in ("group", "t", "p", "y", "R", "rotor_speeds", "v", "d_down", "d_up", "imu"):
        np.testing.assert_array_equal(getattr(bare, name), getattr(sim, name))
    for full in (sim.contiguous, bare.contiguous):
        assert full.p is None and full.y is None and full.imu is None and full.voltage_dev is None
        assert len(full) == 2 * len(fds[0]) and full.rotor_speeds.shape == (len(full), 6)
    assert sim.contiguous.R.shape == (len(sim.contiguous), 3, 3) and sim.contiguous.d_down is not None
    assert bare.contiguous.R is None and bare.contiguous.v is None and bare.contiguous.d_down is None
    np.testing.assert_array_equal(bare.S_lag(0.03), sim.S_lag(0.03))
    moved_bare, moved_sim = bare.with_speed_offset(40.0, 450.0), sim.with_speed_offset(40.0, 450.0)
    np.testing.assert_array_equal(moved_bare.S_lag(0.03), moved_sim.S_lag(0.03))
    assert not np.array_equal(moved_bare.S_lag(0.03), bare.S_lag(0.03))


def test_block_means_known_answer():
    """Rows as means of consecutive kept samples of one recording, rotor speeds as their root mean square: two
    blocks of two in the first recording (a dropped sample starts a new one), one of one in the second."""
    from uavturb.gap.design import GapData, block_means

    n = 6
    group = np.array([0, 0, 0, 0, 0, 1])
    t = np.arange(n) * 0.01
    R = np.stack([np.eye(3) * (k + 1) for k in range(n)])
    w = np.array([[3.0, 1.0], [4.0, 1.0], [0.0, 2.0], [1.0, 2.0], [7.0, 7.0], [5.0, 6.0]])
    full = GapData(group, t, np.arange(3 * n, dtype=float).reshape(n, 3), np.ones((n, 3)), R, w, np.zeros((n, 3)),
                   np.array([0.1, 0.2, np.inf, 0.4, 0.5, 0.6]), np.full(n, np.inf), 1.0, 0.1, ["a", "b"], "mocap",
                   imu=np.zeros(n, bool))
    keep = np.array([True, True, False, True, True, True])
    blocks = block_means(full, keep, 2)
    np.testing.assert_array_equal(blocks.group, [0, 0, 1])
    np.testing.assert_allclose(blocks.t, [0.005, 0.035, 0.05])
    np.testing.assert_allclose(blocks.R, [np.eye(3) * 1.5, np.eye(3) * 4.5, np.eye(3) * 6.0])
    np.testing.assert_allclose(blocks.rotor_speeds, [[np.sqrt(12.5), 1.0], [5.0, np.sqrt(26.5)], [5.0, 6.0]])
    np.testing.assert_allclose(blocks.p[0], [1.5, 2.5, 3.5])
    np.testing.assert_allclose(blocks.d_down, [0.15, 0.45, 0.6])
    np.testing.assert_array_equal(blocks.rows, [0, 1, 3, 4, 5])
    np.testing.assert_array_equal(blocks.block_of, [0, 0, 1, 1, 2])


def test_a_quantised_steady_hover_is_read_as_recorded_not_between_its_changes():
    """Rotor speeds rounded to 1 rad/s: a 6 s hover at a true 147.7 rad/s reads 148 on every row, between changes
    one step at a time before it and one to 149 after. Across that gap, far longer than the stream's others, the
    value held: the flight's speeds are the recorded 148 through the hover, not a line from 148 towards 149 (up to
    1 rad/s, 1.4 % of thrust, high)."""
    rec, _ = _bobbing()
    t = (rec.rotors.t_ns - rec.rotors.t_ns[0]) * 1e-9
    climb = 146.6 + 0.3 * t + 0.8 * np.sin(2 * np.pi * t)  # a rotor's speed in manoeuvres: one step at a time
    true = np.where(t < 3.0, climb, np.where(t < 9.0, 147.7, 147.7 + 0.5 * (t - 9.0)))
    speeds = np.round(np.repeat(true[:, None], rec.rotors.speeds.shape[1], axis=1))
    quantised = dataclasses.replace(rec, rotors=Rotors(rec.rotors.t_ns, speeds))
    assert rotor_repeats(quantised.rotors.speeds) == "rounded"  # every change is one step: repeats of resolution
    fd = flight_data(quantised, window_s=0.1)
    hover = (fd.t > 3.5) & (fd.t < 8.5)
    assert np.all(fd.rotor_speeds[hover] == 148.0)
    assert fd.rotor_fresh is None  # and no row is thinned away


def test_a_value_held_across_a_long_gap_is_not_drawn_as_a_line():
    """Changes every 0.3 s (ESC telemetry at ~3 Hz) are joined by lines; a change 5 s after the last one gets a point
    one row before it carrying the old value, so the 5 s read the value that held."""
    from uavturb.sysid.flight_data import held_across_long_gaps

    rows = np.arange(0, 8_000_000_000, 20_000_000, dtype=np.int64)  # 50 Hz rows for 8 s
    t = np.array([0, 300, 600, 900, 5900, 6200], np.int64) * 1_000_000
    w = np.array([[500.0], [501.0], [502.0], [501.0], [503.0], [502.0]])
    out = held_across_long_gaps(Rotors(t, w), rows)
    assert list(out.t_ns) == [0, 300_000_000, 600_000_000, 900_000_000, 5_880_000_000, 5_900_000_000, 6_200_000_000]
    assert list(out.speeds[:, 0]) == [500.0, 501.0, 502.0, 501.0, 501.0, 503.0, 502.0]
    regular = Rotors(t[:4], w[:4])
    assert held_across_long_gaps(regular, rows) is regular  # nothing long: the stream as it was


def test_a_staggered_column_holds_its_value_across_a_long_gap():
    """One ESC at a time at 3.3 Hz; rotor 0 reports 500 rad/s for 6 s (a steady hover), then 510: its column reads
    500 until its change, not a 6 s line from 500 to 510."""
    rec, _ = _bobbing()
    every = 60
    stag = _staggered(rec.rotors, every)
    t = (stag.t_ns - stag.t_ns[0]) * 1e-9
    speeds = stag.speeds.copy()
    speeds[(t >= 3.0) & (t < 9.0), 0] = 500.0
    speeds[t >= 9.0, 0] = 510.0 + np.floor((t[t >= 9.0] - 9.0) * 200 / every)  # changing again at each update
    speeds[t < 3.0, 0] = 480.0 + np.floor(t[t < 3.0] * 200 / every)
    _, rotors = held_updates(dataclasses.replace(rec, rotors=Rotors(stag.t_ns, speeds)))
    tr = (rotors.t_ns - stag.t_ns[0]) * 1e-9
    hover = (tr > 3.5) & (tr < 8.8)
    assert hover.sum() > 50 and np.all(rotors.speeds[hover, 0] == 500.0)


def test_a_rounded_ramp_is_read_at_its_crossings_without_a_lead():
    """A speed rising 20 rad/s per second, rounded to 1 rad/s in 200 Hz rows, changes every 10 rows. Read on its
    changes it runs half a step (0.5 rad/s, 25 ms) ahead of the truth; read at its crossings (each change placed
    halfway between its rows, at the boundary it crossed), within half a row's motion (0.05 rad/s)."""
    t_ns = np.arange(0, 2_000_000_000, 5_000_000, dtype=np.int64)
    t = t_ns * 1e-9
    true = 150.2 + 20.0 * t
    rounded = np.round(true)[:, None]
    at, values = read_at_crossings(t_ns, rounded)
    inner = (t > 0.1) & (t < 1.9)  # the first and last runs hold their rounded value
    read = np.interp(t_ns[inner].astype(float), at.astype(float), values[:, 0])
    assert np.max(np.abs(read - true[inner])) <= 0.051
    on_changes = update_mask(rounded)
    lead = np.interp(t_ns[inner].astype(float), t_ns[on_changes].astype(float), rounded[on_changes, 0]) - true[inner]
    assert np.mean(lead) == pytest.approx(0.5, abs=0.06)  # what reading on changes did: half a step ahead


def test_a_rounded_value_that_turns_holds_its_rounded_value():
    """A value entering 150 from below and leaving it downwards again lay within 0.5 of 150 all along: the run
    reads 150 on its rows, not a line along the boundary 149.5 it crossed twice. Columns are read on their own
    crossings, each interpolated at the others'."""
    t_ns = np.arange(12, dtype=np.int64) * 10
    a = np.array([148, 149, 149, 150, 150, 150, 150, 149, 149, 148, 148, 148], float)
    b = np.full(12, 300.0)
    at, values = read_at_crossings(t_ns, np.column_stack([a, b]))
    assert list(at) == sorted(set(at)) and at[0] == 0 and at[-1] == 110
    read = dict(zip(at.tolist(), values[:, 0].tolist()))
    assert [read[k] for k in (5, 25, 65, 85)] == [148.5, 149.5, 149.5, 148.5]  # crossings, halfway between rows
    assert read[30] == read[60] == 150.0  # the turn's run, on its first and last rows
    assert 10 not in read and 20 not in read  # a run crossed one way: a line between its crossings
    assert np.all(values[:, 1] == 300.0)


def test_a_rounded_stream_holds_a_row_a_held_one_its_updates():
    """The command-sampling term's hold (rotor_hold_s): one row for speeds whose repeats are rounding (one step at a
    time, runs as irregular as the speed's rate), the update period for a logger's repeats (10 Hz updates in 200 Hz
    rows: 0.1 s), even where each of its updates moves the speed one step: its runs are its period."""
    t_ns = np.arange(0, 4_000_000_000, 5_000_000, dtype=np.int64)
    t = t_ns * 1e-9
    speed = 150.0 + 8.0 * np.sin(1.3 * t) + 4.0 * np.sin(5.1 * t + 1.0)  # rad/s
    rounded = np.round(speed)[:, None].repeat(4, axis=1)
    assert rotor_repeats(rounded) == "rounded" and rotor_hold_s(Rotors(t_ns, rounded)) == pytest.approx(0.005)
    held = speed[(np.arange(len(t)) // 20) * 20][:, None].repeat(4, axis=1)
    assert rotor_repeats(held) == "held" and rotor_hold_s(Rotors(t_ns, held)) == pytest.approx(0.1)
    steps = (150.0 + np.arange(len(t)) // 20 % 2)[:, None].repeat(4, axis=1)  # held, each update one step
    assert rotor_repeats(steps) == "held"
    assert rotor_repeats(speed[:, None].repeat(4, axis=1)) is None


def test_a_rounded_rotor_stream_is_described_as_sampled_on_every_row():
    """Speeds rounded to 1 rad/s repeat at their resolution: stream_updates with ``rounded`` counts their changes
    but gives the rows' rate as the update rate, so a motor lag of 20 ms is not said to need a faster stream; the
    same rows described as held read 25 Hz or so and are."""
    t_ns = np.arange(0, 20_000_000_000, 5_000_000, dtype=np.int64)
    t = t_ns * 1e-9
    speeds = np.round(150.0 + 8.0 * np.sin(1.3 * t) + 4.0 * np.sin(5.1 * t + 1.0))[:, None].repeat(4, axis=1)
    assert rotor_repeats(speeds) == "rounded"
    rounded = stream_updates("rotors0", t_ns, speeds, rounded=True)
    assert rounded.update_rate_hz == pytest.approx(200.0) and rounded.updates < len(t_ns) / 5
    assert "rounded:" in rounded.describe() and slow_for(rounded, needed_rate_hz(0.02)) is None
    held = stream_updates("rotors0", t_ns, speeds)
    assert held.update_rate_hz < 50.0 and slow_for(held, needed_rate_hz(0.02)) is not None
