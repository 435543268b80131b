"""A stream that stops for a while (a logger's dropout, motion capture losing the markers) is not interpolated
across: its dropouts are found, their rows left out of every fit, and the report says where."""

from __future__ import annotations

import numpy as np
import pytest

from uavturb.gap.finder import analyse
from uavturb.io.reader import load_recordings
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
