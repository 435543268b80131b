"""Checkpoints are loaded with ``weights_only=True``, given explicitly: a checkpoint carrying a pickled
payload is refused in one line even with torch's ``TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD=1``, and a run
being resumed keeps its status."""

from __future__ import annotations

import pathlib

import pytest
import torch

from uavturb.cli import main
from uavturb.errors import InputError
from uavturb.io.checkpoint import read_checkpoint


class _Payload:
    """Unpickling it creates the file ``target`` (the harmless stand-in for an attacker's code)."""

    def __init__(self, target: pathlib.Path):
        self.target = target

    def __reduce__(self):
        return (pathlib.Path.touch, (self.target,))


def _poisoned(path: pathlib.Path, target: pathlib.Path) -> pathlib.Path:
    torch.save({"state_dict": {"w": torch.zeros(2)}, "hyper_parameters": {"x": _Payload(target)}}, path)
    return path


@pytest.fixture(autouse=True)
def _escape_hatch(monkeypatch):
    monkeypatch.setenv("TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD", "1")


def test_a_plain_checkpoint_reads_back(tmp_path):
    torch.save({"state_dict": {"w": torch.arange(3.0)}, "epoch": 4}, tmp_path / "ok.ckpt")
    ckpt = read_checkpoint(tmp_path / "ok.ckpt")
    assert ckpt["epoch"] == 4 and ckpt["state_dict"]["w"].tolist() == [0.0, 1.0, 2.0]


def test_a_poisoned_checkpoint_is_refused_without_running_it(tmp_path):
    ran = tmp_path / "payload-ran"
    ckpt = _poisoned(tmp_path / "bad.ckpt", ran)
    with pytest.raises(InputError, match=r"refused: the checkpoint holds Python objects \(getattr\)") as e:
        read_checkpoint(ckpt)
    assert "\n" not in str(e.value) and not ran.exists()


def test_export_refuses_a_poisoned_checkpoint(tmp_path):
    from uavturb.commands.export import load_height_module

    ran = tmp_path / "payload-ran"
    with pytest.raises(InputError, match="refused"):
        load_height_module(checkpoint=_poisoned(tmp_path / "best.ckpt", ran))
    assert not ran.exists()


def test_other_files_are_one_line(tmp_path):
    (tmp_path / "junk.ckpt").write_bytes(b"\x00not a pickle" * 10)
    with pytest.raises(InputError, match="cannot be read as a checkpoint"):
        read_checkpoint(tmp_path / "junk.ckpt")
    torch.save([1, 2], tmp_path / "list.ckpt")
    with pytest.raises(InputError, match="not a Lightning checkpoint"):
        read_checkpoint(tmp_path / "list.ckpt")


def test_resume_refuses_a_poisoned_last_checkpoint_before_touching_the_run(tmp_path, monkeypatch, capsys):
    from uavturb.runs import store
    from uavturb.runs.config import load_config, to_flat_dict
    from uavturb.runs.resume import LAST_CHECKPOINT

    from test_interruptions import _tiny

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    ran = tmp_path / "payload-ran"
    folder = tmp_path / "runs" / "checkpoints" / "r"
    folder.mkdir(parents=True)
    _poisoned(folder / LAST_CHECKPOINT, ran)
    c = store.client()
    rid = c.create_run(store.experiment_id(c, "sig"),
                       tags={"stage": "height", "checkpoint_dir": str(folder)}).info.run_id
    for k, v in to_flat_dict(load_config(_tiny(tmp_path)[2:], experiment="smoke")).items():
        c.log_param(rid, k, str("null" if v is None else v))
    c.set_terminated(rid, "KILLED")
    assert main(["train", "--resume", rid, *_tiny(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "refused: the checkpoint holds Python objects" in err, err
    assert not ran.exists() and not (tmp_path / "sim").exists()
    assert c.get_run(rid).info.status == "KILLED"
