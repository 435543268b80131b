"""Progress output: whole short lines in a log file, a bar redrawn in place on a terminal."""

from __future__ import annotations

import io

from uavturb import progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_in_a_file_is_whole_lines(monkeypatch):
    monkeypatch.setattr(progress, "FILE_INTERVAL", 0.0)  # a line at every update
    log = io.StringIO()
    with progress.progress_bar(40, "generate sim (quick)", "trajectories", stream=log) as bar:
        for k in range(40):
            progress.show_rate(bar, 100 * (k + 1), "samples")
            bar.update(1)
    text = log.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and len(lines) >= 20
    assert max(len(line) for line in lines) < 160
    assert lines[-1].startswith("generate sim (quick): 40/40 trajectories (100 %)") and "4000 samples" in lines[-1]


def test_progress_on_a_terminal_redraws_in_place():
    term = _Terminal()
    with progress.progress_bar(3, "x", "items", stream=term) as bar:
        bar.update(3)
    assert "\r" in term.getvalue() and "3/3" in term.getvalue()


def test_synthetic_data_progress_is_lines(tmp_path, capsys):
    from uavturb.data.synthetic import make_synthetic_dataset

    make_synthetic_dataset(tmp_path / "ds", n_scenes=3, trajs_per_scene=1, T=4, size=8, progress=True)
    err = capsys.readouterr().err
    assert "\r" not in err and err.splitlines()[-1].startswith("synthetic shards: 3/3 trajectories")


def test_stages_show_the_stage_running_and_leave_nothing_behind(monkeypatch):
    """A command's stages in a log file: a line per update naming the stage that runs, with the stages before
    it counted done; a terminal's bar is cleared at the end."""
    monkeypatch.setattr(progress, "FILE_INTERVAL", 0.0)
    log = io.StringIO()
    names = ["reading", "aligning streams", "selecting effects", "writing the report"]
    with progress.Stages("uavturb gap", names, stream=log) as stage:
        for name in names:
            stage(name)
    lines = log.getvalue().splitlines()
    assert any(line.startswith("uavturb gap: 2/4 stages (50 %)") and line.endswith("selecting effects")
               for line in lines), lines
    term = _Terminal()
    with progress.Stages("uavturb gap", names, stream=term) as stage:
        stage("aligning streams")
    drawn = term.getvalue()
    assert "1/4" in drawn and "aligning streams" in drawn
    assert drawn.split("\r")[-2].strip() == "" and drawn.endswith("\r")  # the last drawing is blanks
