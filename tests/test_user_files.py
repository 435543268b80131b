"""No file a user owns is changed without ``--overwrite``: every file output of a command
(``residuals --out``, ``gap --apply``, ``compare``'s tables, a dataset folder's ``manifest.json``)
is refused in one line before the work when it exists, and replaced only with ``--overwrite``."""

from __future__ import annotations

import pytest

from uavturb.cli import main
from uavturb.sim.flights.simulate import generate_flight


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    path = tmp_path_factory.mktemp("userfiles") / "rec"
    generate_flight(vehicle="hex", effects="none", duration=12.0, kind="mixed", seed=3, out=path)
    return path


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_residuals_out_needs_overwrite(tmp_path, capsys, flight):
    out = tmp_path / "mine.csv"
    out.write_text("user's table")
    assert main(["residuals", str(flight), "--out", str(out)]) == 2
    assert _one_line(capsys) == f"uavturb residuals: error: {out}: already exists (use --overwrite to replace it)"
    assert out.read_text() == "user's table"
    assert main(["residuals", str(flight), "--out", str(out), "--overwrite"]) == 0
    assert out.read_text().startswith("t [s],timestamp [ns],F_x [N]")


def test_gap_apply_needs_overwrite_and_nothing_is_written(tmp_path, capsys, flight):
    conf = tmp_path / "physics.yaml"
    conf.write_text("mine: true\n")
    out = tmp_path / "report"
    assert main(["gap", str(flight), "--out", str(out), "--apply", str(conf), "--no-mlflow"]) == 2
    assert _one_line(capsys) == f"uavturb gap: error: {conf}: already exists (use --overwrite to replace it)"
    assert conf.read_text() == "mine: true\n" and not out.exists()


def test_two_gap_runs_to_one_out_the_second_does_not_replace_the_first(tmp_path, capsys, flight):
    out = tmp_path / "report"
    assert main(["gap", str(flight), "--out", str(out), "--no-mlflow"]) == 0
    first = (out / "report.json").read_bytes()
    assert main(["gap", str(flight), "--out", str(out), "--no-mlflow", "--seed", "1"]) == 2
    assert (out / "report.json").read_bytes() == first


def test_generate_sim_never_replaces_a_users_manifest(tmp_path, capsys):
    out = tmp_path / "data"
    out.mkdir()
    (out / "manifest.json").write_text('{"mine": 1}')
    assert main(["generate", "sim", "--preset", "tiny", "--out", str(out)]) == 2
    line = _one_line(capsys)
    assert line.startswith(f"uavturb generate: error: {out / 'manifest.json'}: is not a dataset manifest "
                           "uavturb wrote"), line
    assert (out / "manifest.json").read_text() == '{"mine": 1}' and sorted(p.name for p in out.iterdir()) == [
        "manifest.json"]
