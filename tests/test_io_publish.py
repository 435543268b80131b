"""The output-folder rule: nothing uavturb did not write is ever deleted."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from uavturb.errors import InputError
from uavturb.io.publish import (
    MARKER,
    check_apart,
    check_output_folder,
    clean_stale,
    publish_file,
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
    with pytest.raises(InputError, match="is the working folder"):
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
    assert code == 2 and len(err) == 1 and "is the working folder" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mlflow.db"]


# --- the check repeated at the moment of replacing ----------------------------------------------


def test_a_folder_created_at_out_while_writing_is_never_replaced(tmp_path):
    out = tmp_path / "report"
    for content in ([], ["mine.txt"]):  # the user's empty folder, then one with a file
        with pytest.raises(InputError, match="was created or filled while this command ran"):
            with publish_folder(out, overwrite=False, command="test") as tmp:
                (tmp / "result.txt").write_text("new")
                out.mkdir()
                for name in content:
                    (out / name).write_text("precious")
        assert sorted(p.name for p in out.iterdir()) == content
        assert [p.name for p in tmp_path.iterdir()] == ["report"]  # no temporary folder left
        for name in content:
            assert (out / name).read_text() == "precious"
        out.rmdir() if not content else None


def test_two_writers_to_one_out_the_second_is_refused(tmp_path):
    out = tmp_path / "report"
    with pytest.raises(InputError, match="was created or filled while this command ran"):
        with publish_folder(out, overwrite=False, command="second") as tmp2:
            (tmp2 / "result.txt").write_text("second")
            _publish(out, "first")  # the first writer finishes while the second works
    assert (out / "result.txt").read_text() == "first"


def test_a_file_added_to_our_folder_while_writing_is_kept(tmp_path):
    out = tmp_path / "report"
    _publish(out, "first")
    with pytest.raises(InputError, match="changed while this command ran: holds 'notes.txt'"):
        with publish_folder(out, overwrite=True, command="test") as tmp:
            (tmp / "result.txt").write_text("second")
            (out / "notes.txt").write_text("precious")
    assert (out / "notes.txt").read_text() == "precious" and (out / "result.txt").read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_stale_temporary_folders_of_a_killed_run_are_cleaned(tmp_path):
    import signal
    import subprocess
    import sys

    out = tmp_path / "report"
    code = ("import sys, time; from uavturb.io.publish import publish_folder\n"
            f"with publish_folder({str(out)!r}, overwrite=False, command='t') as tmp:\n"
            "    (tmp / 'half.txt').write_text('x'); print(tmp, flush=True); time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    tmp = Path(proc.stdout.readline().strip())
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert tmp.is_dir() and tmp.parent == tmp_path  # what SIGKILL leaves
    alive = tmp_path / f"{tmp.name.rsplit('-', 1)[0]}-{os.getpid()}.abcdefgh.tmp"  # a live process's (ours)
    alive.mkdir()
    foreign = tmp_path / ".report.user.tmp"  # not of our naming: never touched
    foreign.mkdir()
    _publish(out)
    assert not tmp.exists() and alive.is_dir() and foreign.is_dir() and (out / "result.txt").is_file()
    assert clean_stale(out) == []


def test_file_outputs_need_overwrite_and_are_never_replaced_if_they_appear(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text("user's")
    with pytest.raises(InputError, match="already exists \\(use --overwrite to replace it\\)"):
        write_text_atomic(path, "ours", overwrite=False)
    assert path.read_text() == "user's"
    write_text_atomic(path, "ours", overwrite=True)
    assert path.read_text() == "ours"
    late = tmp_path / "late.csv"
    with pytest.raises(InputError, match="was created while this command ran"):
        with publish_file(late, overwrite=False) as tmp:
            tmp.write_text("ours")
            late.write_text("user's")
    assert late.read_text() == "user's" and sorted(p.name for p in tmp_path.iterdir()) == ["late.csv", "table.csv"]


def test_out_dot_in_an_empty_folder_is_refused_up_front(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for out in (".", "..", str(tmp_path)):
        with pytest.raises(InputError, match="is the working folder"):
            check_output_folder(out, overwrite=True)
    assert list(tmp_path.iterdir()) == []


def test_an_output_apart_from_the_inputs(tmp_path):
    rec = tmp_path / "rec"
    (rec / "mav0").mkdir(parents=True)
    (rec / "vehicle.yaml").write_text("mass: 1\n")
    check_apart(tmp_path / "report", [rec])  # beside it: fine
    check_apart(tmp_path / "rec_report", [rec])  # a name that merely starts alike: fine
    for out, match in [(rec, "is an input of this command"), (tmp_path, "holds an input of this command"),
                       (rec / "report", "lies inside an input of this command"),
                       (rec / "vehicle.yaml", "lies inside an input of this command")]:
        with pytest.raises(InputError, match=match):
            check_apart(out, [rec])
    with pytest.raises(InputError, match="--apply would replace or change it"):
        check_apart(rec / "vehicle.yaml", [rec / "vehicle.yaml"], what="--apply")
