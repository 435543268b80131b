"""The output-folder rule: nothing uavturb did not write is ever deleted."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from uavturb.errors import InputError
from uavturb.io.publish import (
    MARKER,
    check_output_folder,
    publish_folder,
    write_text_atomic,
)


def _publish(out: Path, text: str = "x", *, overwrite: bool = False) -> None:
    with publish_folder(out, overwrite=overwrite, command="test") as tmp:
        (tmp / "result.txt").write_text(text)
        (tmp / "sub").mkdir()
        (tmp / "sub" / "plot.png").write_bytes(b"png")


def test_new_folder_with_missing_parents_is_created_with_marker(tmp_path):
    out = tmp_path / "a" / "b" / "report"
    _publish(out)
    assert (out / "result.txt").read_text() == "x"
    assert (out / MARKER).is_file()
    assert sorted(p.name for p in tmp_path.joinpath("a", "b").iterdir()) == ["report"]  # no temporary left


def test_foreign_folder_is_never_touched_even_with_overwrite(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "my_notes.txt").write_text("precious")
    for overwrite in (False, True):
        with pytest.raises(InputError, match="not written by uavturb"):
            _publish(out, overwrite=overwrite)
    assert (out / "my_notes.txt").read_text() == "precious"
    assert sorted(p.name for p in out.iterdir()) == ["my_notes.txt"]


def test_current_directory_is_refused(tmp_path, monkeypatch):
    (tmp_path / "checkout.py").write_text("code")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match="not written by uavturb"):
        check_output_folder(".", overwrite=True)
    assert (tmp_path / "checkout.py").read_text() == "code"


def test_our_folder_needs_overwrite_then_is_replaced_whole(tmp_path):
    out = tmp_path / "report"
    _publish(out, "first")
    with pytest.raises(InputError, match="already exists.*--overwrite"):
        _publish(out, "second")
    assert (out / "result.txt").read_text() == "first"
    _publish(out, "second", overwrite=True)
    assert (out / "result.txt").read_text() == "second"


def test_our_folder_with_a_users_file_added_is_refused_and_kept(tmp_path):
    out = tmp_path / "report"
    _publish(out, "first")
    (out / "my_notes.txt").write_text("precious")
    with pytest.raises(InputError, match="my_notes.txt"):
        _publish(out, "second", overwrite=True)
    assert (out / "my_notes.txt").read_text() == "precious"
    assert (out / "result.txt").read_text() == "first"


def test_empty_existing_folder_is_accepted(tmp_path):
    out = tmp_path / "empty"
    out.mkdir()
    _publish(out)
    assert (out / "result.txt").is_file()


def test_failure_inside_leaves_previous_result_and_no_temporary(tmp_path):
    out = tmp_path / "report"
    _publish(out, "first")
    with pytest.raises(RuntimeError):
        with publish_folder(out, overwrite=True, command="test") as tmp:
            (tmp / "result.txt").write_text("half")
            raise RuntimeError("boom")
    assert (out / "result.txt").read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_unwritable_places_are_one_line(tmp_path):
    afile = tmp_path / "a_file"
    afile.write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        _publish(afile / "report")
    with pytest.raises(InputError, match="not a folder"):
        _publish(afile)
    with pytest.raises(InputError) as e:  # /proc refuses new entries even for root
        _publish(Path("/proc/uavturb-report"))
    assert "\n" not in str(e.value)
    with pytest.raises(InputError):
        write_text_atomic("/proc/uavturb-table.md", "x")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_parent_is_named(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(InputError, match="not writable"):
            check_output_folder(ro / "report", overwrite=False)
    finally:
        ro.chmod(0o700)


def test_evaluate_out_dot_stops_before_anything(tmp_path, monkeypatch, capsys):
    from uavturb.cli import main

    (tmp_path / "mlflow.db").write_text("store")
    monkeypatch.chdir(tmp_path)
    code = main(["evaluate", "--run", "nope", "rec", "--out", ".", "--overwrite", "--no-mlflow"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "not written by uavturb" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mlflow.db"]
