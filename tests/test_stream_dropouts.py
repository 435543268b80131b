"""A stream that stops for a while (a logger's dropout, motion capture losing the markers) is not interpolated
across: its dropouts are found, their rows left out of every fit, and the report says where."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.gap.finder import analyse
from uavturb.io.reader import load_recordings
from uavturb.io.stream_faults import frozen_rows
from uavturb.sim.flights.simulate import generate_flight
from uavturb.sysid.flight_data import flight_data
from uavturb.sysid.streams import MIN_DROPOUT_S, dropouts
from uavturb.sysid.identification import usable_mask

NS = 1_000_000_000


def test_dropouts_are_long_stretches_without_a_sample_not_jitter():
    t = np.arange(0, 10 * NS, NS // 100)  # 100 Hz for 10 s
    assert dropouts(t) == []
    jittered = t.copy()
    jittered[500:503] += NS // 50  # a few rows two steps apart: jitter
    assert dropouts(np.sort(jittered)) == []
    cut = np.r_[t[t < 4 * NS], t[t >= 4.5 * NS]]
    assert dropouts(cut) == [(int(cut[cut < 4 * NS][-1]), int(4.5 * NS))]
    held_3hz = np.arange(0, 60 * NS, NS // 3)  # a 3 Hz stream missing one update is still a 3 Hz stream
    assert dropouts(np.delete(held_3hz, 50)) == []
    gone = np.delete(held_3hz, np.arange(50, 60))  # ... missing ten (3.7 s) has a dropout
    assert len(dropouts(gone)) == 1
    fast = np.arange(0, NS, NS // 1000)  # 1 kHz: a 20 ms gap is under MIN_DROPOUT_S
    assert MIN_DROPOUT_S > 0.02 and dropouts(np.delete(fast, np.arange(100, 119))) == []


def _cut_rotors(path, a, b):
    csv = path / "mav0" / "rotors0" / "data.csv"
    lines = csv.read_text().splitlines()
    t0 = int((path / "mav0" / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()[1].split(",")[0])
    csv.write_text("\n".join([lines[0]] + [ln for ln in lines[1:]
                                           if not a <= (int(ln.split(",")[0]) - t0) / NS < b]) + "\n")


@pytest.fixture(scope="module")
def cut_flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("dropouts")
    paths = []
    for seed in (3, 4):
        path = root / f"cut-{seed}"
        generate_flight(vehicle="hex", effects="ground_effect:mu=2", duration=40.0, kind="low_passes", seed=seed,
                        out=path)
        _cut_rotors(path, 12.0, 15.0)  # the rotor stream stops for 3 s in the middle of each flight
        paths.append(path)
    return paths


def test_rows_in_a_dropout_are_not_covered(cut_flights):
    rec = load_recordings(cut_flights[:1])[0]
    fd = flight_data(rec)
    assert [g[0] for g in fd.gaps] == ["mav0/rotors0/data.csv"]
    _, a, b = fd.gaps[0]
    assert a == pytest.approx(12.0, abs=0.01) and b == pytest.approx(15.0, abs=0.01)
    inside = (fd.t > a) & (fd.t < b)
    assert inside.sum() > 500 and not fd.covered[inside].any()
    margin = fd.window * fd.dt
    assert fd.covered[(fd.t < a - 1.01 * margin) | (fd.t > b + 1.01 * margin)].all()
    assert not usable_mask(fd, rec.vehicle)[inside].any()  # identify leaves them out too


def test_the_gap_finder_leaves_a_dropout_out_and_says_where(cut_flights):
    report, extras = analyse(load_recordings(cut_flights), {})
    named = {e["name"]: e for e in report["effects"]}
    assert list(named) == ["ground_effect"] and named["ground_effect"]["params"]["mu"] == pytest.approx(2.0, rel=0.1)
    found = report["streams"]["dropouts"]
    assert [(d["recording"], d["stream"]) for d in found] == [(str(p), "mav0/rotors0/data.csv") for p in cut_flights]
    assert all(d["t_start"] == pytest.approx(12.0, abs=0.01) and d["t_end"] == pytest.approx(15.0, abs=0.01)
               for d in found)
    # no row of the fits lies where the rotor speeds were missing (interpolated across, they were a 3 s ramp)
    data = extras["data"]
    assert not np.any((data.t > 12.0) & (data.t < 15.0)) and np.sum(data.t < 12.0) > 100


def test_a_value_that_holds_while_its_rows_go_on_is_no_dropout(tmp_path):
    """Rotor speeds repeating one value for 5 s (quantised in a steady hover, or a logger holding them) are rows,
    not a gap: nothing is left out as a dropout (the rows' timestamps count, not the value's changes)."""
    path = tmp_path / "steady"
    generate_flight(vehicle="hex", effects="", duration=20.0, kind="low_passes", seed=5, out=path)
    csv = path / "mav0" / "rotors0" / "data.csv"
    lines = csv.read_text().splitlines()
    t0 = int(lines[1].split(",")[0])
    steady = lines[1].split(",", 1)[1]

    def rounded(ln):  # speeds quantised to 5 rad/s (most updates repeat), and one value for 5-10 s
        t = int(ln.split(",")[0])
        w = ",".join(f"{5 * round(float(x) / 5):.1f}" for x in ln.split(",")[1:])
        return f"{t},{steady}" if 5.0 <= (t - t0) / NS < 10.0 else f"{t},{w}"
    csv.write_text("\n".join([lines[0]] + [rounded(ln) for ln in lines[1:]]) + "\n")
    fd = flight_data(load_recordings([path])[0])
    assert fd.gaps == [] and fd.covered is None


def _rewrite_ground_truth(path, fn):
    csv = path / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = csv.read_text().splitlines()
    t0 = int(lines[1].split(",")[0])
    out, last = [lines[0]], None
    for ln in lines[1:]:
        cells = ln.split(",")
        t = (int(cells[0]) - t0) / NS
        cells, last = fn(t, cells, last)
        out.append(",".join(cells))
    csv.write_text("\n".join(out) + "\n")


@pytest.fixture(scope="module")
def lost_tracking(tmp_path_factory):
    """One flight three ways a motion capture loses the vehicle: its last pose written on (12-14 s), empty and NaN
    fields (20-21.5 s), the position alone frozen while the velocities go on (30-31 s)."""
    path = tmp_path_factory.mktemp("lost") / "lost"
    generate_flight(vehicle="hex", effects="ground_effect:mu=2", duration=40.0, kind="low_passes", seed=3, out=path)

    def lose(t, cells, last):
        if 12.0 <= t < 14.0 and last is not None:
            return [cells[0]] + last[1:], last
        if 20.0 <= t < 21.5:
            return [cells[0]] + ["", "NaN"] + cells[3:], cells
        if 30.0 <= t < 31.0 and last is not None:
            return [cells[0]] + last[1:4] + cells[4:], [cells[0]] + last[1:4] + cells[4:]
        return cells, cells
    _rewrite_ground_truth(path, lose)
    return path


def test_a_motion_capture_that_lost_the_vehicle_leaves_dropouts_said(lost_tracking):
    """Each way of losing the vehicle is read as a dropout of the ground truth at its times, and said: the frozen
    pose had been refused as a gyroscope at odds with the attitude, the NaN rows as a malformed file, the frozen
    position read as a vehicle standing still."""
    rec = load_recordings([lost_tracking])[0]
    notes = " ".join(rec.read_notes)
    assert "rows with a value missing (empty or NaN: tracking lost) left out, in 1 stretch" in notes
    assert "rows repeat a position frozen for longer than the stream's changes allow, in 2 stretches" in notes
    fd = flight_data(rec)
    found = [(round(a, 1), round(b, 1)) for s, a, b in fd.gaps if s == "mav0/state_groundtruth_estimate0/data.csv"]
    assert found == [(12.0, 14.0), (20.0, 21.5), (30.0, 31.0)]


def test_the_gap_finder_reads_a_flight_that_lost_tracking_as_its_clean_self(lost_tracking):
    report, extras = analyse(load_recordings([lost_tracking]), {})
    named = {e["name"]: e for e in report["effects"]}
    assert list(named) == ["ground_effect"] and named["ground_effect"]["params"]["mu"] == pytest.approx(2.0, rel=0.1)
    data = extras["data"]
    for a, b in ((12.0, 14.0), (20.0, 21.5), (30.0, 31.0)):
        assert not np.any((data.t > a + 0.05) & (data.t < b - 0.05))


def test_frozen_rows_are_runs_the_velocities_or_every_value_contradict():
    """Known answers: a still hover whose positions round to 1 mm repeats them with noisy velocities (no run is
    frozen); the same positions frozen while the velocities say 1 m/s are; every value repeated is."""
    rng = np.random.default_rng(0)
    t = np.arange(2000) * 5_000_000  # 200 Hz, 10 s
    p = np.round(np.column_stack([np.zeros(2000), np.zeros(2000), 0.5 + rng.normal(0, 2e-4, 2000)]), 3)
    v = rng.normal(0, 5e-3, (2000, 3))
    q = np.tile([1.0, 0, 0, 0], (2000, 1)) + rng.normal(0, 1e-5, (2000, 4))
    assert frozen_rows(t, p, q, v).sum() == 0
    moving = p.copy()
    moving[:, 0] = np.arange(2000) * 0.005  # 1 m/s along x
    v_moving = v + [1.0, 0, 0]
    moving[801:1000] = moving[800]  # position frozen 4.0-5.0 s
    assert np.array_equal(np.flatnonzero(frozen_rows(t, moving, q, v_moving)), np.arange(801, 1000))
    all_same_p, all_same_q, all_same_v = moving.copy(), q.copy(), v_moving.copy()
    for a in (all_same_p, all_same_q, all_same_v):
        a[1401:1500] = a[1400]
    assert set(np.flatnonzero(frozen_rows(t, all_same_p, all_same_q, all_same_v))) >= set(range(1401, 1500))
