"""gap.finder.analyse on recorded speeds with a decisive offset: the analysis runs again on the moved speeds, and
the first analysis's end (its surface curve and honest errors, which only its report needs) runs in a forked child
meanwhile. The same report as one after the other, whichever process computed it; an error in the next analysis
is answered at once."""

from __future__ import annotations

import os
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from uavturb.errors import InputError
from uavturb.gap import finder
from uavturb.gap.finder import MOVED_SPEEDS_STAGE, Checkpoint, analyse
from uavturb.numerics import processes

from processes_helpers import pid_written, process_gone

pytestmark = pytest.mark.skipif(not processes.forking_possible(), reason="forks only on Linux with two cores")

DECISIVE = SimpleNamespace(decisive=True, delta=12.0, w_hover=150.0)


def _fake_analysis(end_fails_in_child: bool = False, end_sleeps_s: float = 0.0, pid_file: Path | None = None):
    """An analysis that pauses where a real one does (a decisive offset read, 20,000 rows in six folds) and ends
    with a report of who computed its end and the first number it draws there from numpy's global generator."""

    def analysis(recordings, sim, *, seed, height_uncertainty, progress):
        progress("aligning the streams")
        np.random.seed(seed)
        np.random.random()
        yield Checkpoint(DECISIVE, 20_000, 6)
        progress("the surface curve")
        if pid_file is not None:
            pid_file.write_text(str(os.getpid()))
        if end_fails_in_child and processes.in_forked_child():
            raise RuntimeError("the child's end fails")
        time.sleep(end_sleeps_s)
        progress("honest errors")
        return {"pid": os.getpid(), "draw": float(np.random.random())}, {"first": True}

    return analysis


def _analysed(monkeypatch, analysis, moved=None):
    """``analyse`` with ``analysis`` for the real one; the next analysis draws from the same generator (as a real
    one seeds and draws); what it was shown, and the report and moves it returns."""
    def on_moved_speeds(recordings, sim, offset, seed, height_uncertainty, at_checkpoint):
        np.random.seed(seed + 1)
        np.random.random(5)
        if moved is not None:
            moved()
        return {"again": True}, {"last": True}, [offset.delta]

    shown = []
    monkeypatch.setattr(finder, "_analysis", analysis)
    monkeypatch.setattr(finder, "_on_moved_speeds", on_moved_speeds)
    monkeypatch.setattr(finder, "read_on_moved_speeds", lambda report, again, readings: (report, again, readings))
    (report, again, readings), extras = analyse([], {}, seed=3, progress=shown.append)
    return shown, report, again, readings, extras


def test_the_first_analysis_ends_in_a_child_with_the_report_it_gives_alone(monkeypatch):
    shown, report, again, readings, extras = _analysed(monkeypatch, _fake_analysis())
    assert report["pid"] != os.getpid()
    assert again == {"again": True} and readings == [12.0] and extras == {"last": True}
    # the first one's stages run aside, unseen; the next analysis's stage is shown
    assert shown == ["aligning the streams", MOVED_SPEEDS_STAGE]
    # alone, one after the other: the same report, its stages shown in order
    monkeypatch.setattr(finder, "forking_worth", lambda rows, fits: False)
    shown_alone, alone, *_ = _analysed(monkeypatch, _fake_analysis())
    assert alone["pid"] == os.getpid() and alone["draw"] == report["draw"]
    assert shown_alone == ["aligning the streams", "the surface curve", "honest errors", MOVED_SPEEDS_STAGE]
    # where no child can be forked (one core), in turn as well: nothing is held back for a child that never comes
    monkeypatch.undo()
    monkeypatch.setattr(processes, "usable_cores", lambda: 1)
    shown_one_core, one_core, *_ = _analysed(monkeypatch, _fake_analysis())
    assert one_core == alone and shown_one_core == shown_alone


def test_an_end_that_fails_in_the_child_is_computed_here_from_where_it_paused(monkeypatch):
    monkeypatch.setattr(finder, "forking_worth", lambda rows, fits: False)
    _, alone, *_ = _analysed(monkeypatch, _fake_analysis())
    monkeypatch.undo()
    shown, report, *_ = _analysed(monkeypatch, _fake_analysis(end_fails_in_child=True))
    # computed here after the next analysis drew from the same generator: drawn as where it paused
    assert report["pid"] == os.getpid() and report["draw"] == alone["draw"]
    assert shown == ["aligning the streams", MOVED_SPEEDS_STAGE]


def test_an_error_in_the_next_analysis_stops_the_first_ones_end(monkeypatch, tmp_path):
    pid_file = tmp_path / "pid"

    def fails():
        pid_written(pid_file)  # the child has started the first analysis's end
        raise InputError("rec/mav0/rotors0/data.csv", "too few rows on the moved speeds")

    with pytest.raises(InputError, match="too few rows on the moved speeds"):
        _analysed(monkeypatch, _fake_analysis(end_sleeps_s=60.0, pid_file=pid_file), moved=fails)
    pid = pid_written(pid_file)
    assert pid != os.getpid() and process_gone(pid)


@pytest.mark.parametrize("counts, called_at", [([True, False], [1]), ([True, True, True], [2]), ([False], [0])])
def test_at_checkpoint_is_called_at_the_analysis_on_moved_speeds_that_gives_the_report(monkeypatch, counts,
                                                                                        called_at):
    """The analyses on moved speeds go on while their offset counts (three at most): ``at_checkpoint`` is called once,
    at the checkpoint of the last one, with what that analysis's extras hold."""
    passes = iter(range(len(counts)))

    def analysis(recordings, sim, *, seed, height_uncertainty, progress=None):
        k = next(passes)
        offset = SimpleNamespace(counts=counts[k])
        yield Checkpoint(offset, 20_000, 6, {"data": f"pass {k}"})
        return ({"nominal": {"rotor_speed_offset": {"counts": counts[k], "delta_rad_s": 1.0}}},
                {"data": f"pass {k}"})

    monkeypatch.setattr(finder, "_analysis", analysis)
    monkeypatch.setattr(finder, "rotor_speeds_moved", lambda r, delta, w_hover: r)
    seen = []
    report, extras, readings = finder._on_moved_speeds([], {}, DECISIVE, 0, 0.0, seen.append)
    assert seen == [{"data": f"pass {k}"} for k in called_at] and extras == seen[0]
    assert len(readings) == len(counts) == called_at[0] + 1
