"""Start-up of the ``uavturb`` command: the parser imports no numerical stack just to list choices, the
lists still show where help is printed, a bad value still gets one line listing the allowed ones, and
``uavturb gap`` loads neither scipy.signal nor scipy.stats (together ~1.2 s of its start-up)."""

import subprocess
import sys

import pytest

from uavturb.cli import _parser, main
from uavturb.runs.config import DEFAULT_SPEC, load_spec
from uavturb.sim.dataset.presets import PRESETS

HEAVY = ("numpy", "scipy", "pandas", "omegaconf", "torch", "mlflow", "matplotlib")


def modules_after(code: str) -> list[str]:
    """Top-level packages of HEAVY loaded by ``code`` in a fresh interpreter, and scipy.signal / scipy.stats."""
    probe = (f"import sys\n{code}\n"
             "print(sorted({m.split('.')[0] for m in sys.modules if m.split('.')[0] in " + repr(HEAVY) + "}"
             " | {m for m in sys.modules if m in ('scipy.signal', 'scipy.stats')}))")
    res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    return eval(res.stdout.strip().splitlines()[-1])


def test_the_parser_and_help_load_no_numerical_stack():
    assert modules_after("from uavturb.cli import _parser; _parser()") == []
    assert modules_after("import contextlib, io\nfrom uavturb.cli import main\n"
                         "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
                         "    main(['--help'])") == []


def test_the_gap_command_loads_neither_scipy_signal_nor_stats():
    loaded = modules_after("import uavturb.commands.gap, uavturb.gap.report\n"
                           "from uavturb.cli import _parser; _parser()")
    assert "scipy" in loaded and "scipy.signal" not in loaded and "scipy.stats" not in loaded


@pytest.mark.parametrize("argv", [["generate", "sim", "--help"], ["generate", "normals", "--help"]])
def test_preset_help_lists_the_presets(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 0
    out = " ".join(capsys.readouterr().out.split())  # argparse wraps the lines
    assert f"--preset PRESET {' | '.join(PRESETS)} (default quick)" in out and len(PRESETS) >= 4


def test_sweep_help_lists_the_profiles(capsys):
    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert f"(ablation: {', '.join(load_spec(DEFAULT_SPEC).profiles)}; default quick)" in out
    assert "quick, paper" in out  # the shipped profiles, not an empty list


def test_an_unknown_preset_or_profile_is_one_line_listing_the_allowed(tmp_path, capsys):
    for what in ("sim", "normals"):
        assert main(["generate", what, "--preset", "nope", "--out", str(tmp_path / what)]) == 2
        err = capsys.readouterr().err
        assert err == f"uavturb generate: error: --preset: unknown preset 'nope' (known: {', '.join(PRESETS)})\n"
        assert not (tmp_path / what).exists()
    assert main(["sweep", "ablation", "--profile", "nope"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--profile: no profile 'nope'" in err and "quick, paper" in err


def test_parsing_is_unchanged_by_the_late_lists():
    args = _parser().parse_args(["generate", "sim", "--out", "d"])
    assert args.preset == "quick" and args.what == "sim"
    assert _parser().parse_args(["sweep", "ablation", "--preset", "gpu"]).profile == "gpu"
    with pytest.raises(SystemExit):
        _parser().parse_args(["bench", "nope"])  # bench targets are still choices, checked by argparse
