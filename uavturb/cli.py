"""The ``uavturb`` command: parses arguments and calls library functions, nothing more."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Callable

from uavturb.errors import InputError, Interrupted, UavturbError, raise_on_signals

# Each command imports its module (uavturb.commands, uavturb.runs, uavturb.bench, ...) inside its
# handler below, not here: start-up time (`uavturb --help` and `uavturb gap` never load torch,
# Lightning or MLflow).


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("uavturb")
    except PackageNotFoundError:  # a checkout on PYTHONPATH, not installed
        import uavturb

        return uavturb.__version__


def _renamed(new: str) -> type[argparse.Action]:
    """An option kept under its old spelling: works as ``new`` and prints a deprecation line."""

    class Renamed(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            print(f"{parser.prog}: {option_string} is deprecated, use {new}", file=sys.stderr)
            setattr(namespace, self.dest, values)

    return Renamed


#: what ``--vehicle`` takes (:func:`uavturb.io.vehicle_file.named_vehicle`)
VEHICLE_HELP = "built-in vehicle (quad, hex), shipped (firefly) or vehicle.yaml"


class _Later:
    """Names a help text lists, looked up only when that help page is printed: the modules holding them
    are slow to import (the presets load numpy and scipy, the sweep file OmegaConf; ~1.5 s), which neither
    ``uavturb --help`` nor any command's start-up should pay. The library checks the value given
    (an unknown preset or profile: one line naming the option and listing the allowed values)."""

    def __init__(self, lookup: Callable[[], str]) -> None:
        self.lookup = lookup

    def __str__(self) -> str:
        return self.lookup()


def _later(action: argparse.Action, **names: Callable[[], str]) -> None:
    """Let ``action``'s help text show ``%(KEY)s`` for each of ``names``, filled when the help is printed
    (argparse fills a help text's ``%(...)s`` from the action's attributes, as it does ``%(default)s``)."""
    for key, lookup in names.items():
        setattr(action, key, _Later(lookup))


def _sim_presets() -> str:
    from uavturb.sim.dataset.presets import PRESETS

    return " | ".join(PRESETS)


def _sweep_profiles() -> str:
    from uavturb.runs.config import DEFAULT_SPEC, load_spec

    return ", ".join(load_spec(DEFAULT_SPEC).profiles)


def _add_mlflow_experiment(s: argparse.ArgumentParser) -> None:
    s.add_argument("--mlflow-experiment", dest="mlflow_experiment", default=None, metavar="NAME",
                   help="MLflow experiment (default: the sweep file's, uavturb-ablation)")
    s.add_argument("--experiment", dest="mlflow_experiment", action=_renamed("--mlflow-experiment"),
                   help=argparse.SUPPRESS)


def _add_identify(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("identify", help="identify k_T, k_M and inertia from flights (the paper's least squares)")
    s.add_argument("recordings", nargs="+", metavar="REC", help="recording folders (recordings.md layout)")
    s.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    s.add_argument("--model", default="auto", choices=["auto", "general", "jx=jy"],
                   help="inertia model: J_x != J_y, the paper's J_x = J_y, or chosen by the data (default)")
    s.add_argument("--vehicle", help=f"{VEHICLE_HELP} for folders without one (raw EuRoC)")


def _add_residuals(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("residuals", help="ground-truth turbulence: residual force of the identified model")
    s.add_argument("recording", metavar="REC")
    s.add_argument("--out", required=True, help="output file: .csv or .parquet")
    s.add_argument("--source", default="auto", choices=["auto", "imu", "mocap"],
                   help="IMU specific force (default where present) or differentiated MoCap velocity")
    s.add_argument("--derivative", default="savgol", choices=["savgol", "forward"],
                   help="MoCap derivative: Savitzky-Golay or the paper's one-step forward difference")
    s.add_argument("--params", default="identified", choices=["identified", "nominal"],
                   help="model constants: identified on this flight (default) or vehicle.yaml's")
    s.add_argument("--vehicle", help=f"{VEHICLE_HELP} for folders without one")
    s.add_argument("--overwrite", action="store_true", help="replace an existing output file")


def _euroc_arguments(s: argparse.ArgumentParser) -> None:
    s.add_argument("bag", metavar="BAG", help="the sequence's .bag (rotor speeds from /fcu/motor_speed)")
    s.add_argument("--asl", metavar="ASL_DIR", help="the sequence's ASL folder: ground truth, IMU, point cloud, cam0")
    s.add_argument("--vehicle", default="firefly", help=f"{VEHICLE_HELP} (default firefly)")
    s.add_argument("--rotor-speed-scale", type=float, default=None, help="rad/s per unit of /fcu/motor_speed")
    s.add_argument("--out", required=True, metavar="REC", help="recording folder to create")
    s.add_argument("--overwrite", action="store_true")


def _log_arguments(s: argparse.ArgumentParser) -> None:
    """Options shared by `import ulog` and `import csv`."""
    s.add_argument("--vehicle", required=True, help=f"{VEHICLE_HELP} (a file: rotor geometry in its own order)")
    s.add_argument("--out", required=True, metavar="REC", help="recording folder to create")
    s.add_argument("--floor-z", type=float, default=None, metavar="Z",
                   help="height [m] of a flat floor in the recording's world (z up), written as pointcloud0 "
                        "(default: no point cloud)")
    s.add_argument("--rotor-plane-z", type=float, default=None, metavar="Z",
                   help="height [m] of the rotor plane above the body origin (default: vehicle.yaml's)")
    s.add_argument("--overwrite", action="store_true", help="replace an output folder that uavturb wrote")


def _add_import(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("import", help="a flight log (EuRoC bag, PX4 ULog, any CSV with a map) as a recording")
    isub = s.add_subparsers(dest="what", required=True, metavar="WHAT")
    _euroc_arguments(isub.add_parser("euroc", help="a raw EuRoC sequence (ROS bag, optionally its ASL folder)"))
    u = isub.add_parser("ulog", help="a PX4 log (.ulg), read with pyulog")
    u.add_argument("log", metavar="LOG.ulg")
    _log_arguments(u)
    u.add_argument("--motor-order", default=None, metavar="I,J,...",
                   help="vehicle.yaml rotor i is ESC / actuator output I_i (default 0,1,2,...)")
    u.add_argument("--rotors", default="auto", choices=["auto", "esc", "outputs"],
                   help="rotor speeds from esc_status rpm (measured) or actuator_outputs through --thrust-map "
                        "(commanded); auto: ESC rpm where the log has any")
    u.add_argument("--thrust-map", default=None, metavar="FILE.yaml",
                   help="thrust per rotor as a polynomial in the output and the battery voltage (README)")
    u.add_argument("--height", default="local", choices=["local", "dist_bottom"],
                   help="the height from the local position's z (default), or from dist_bottom, PX4's height over the "
                        "ground from a range sensor (a barometer's height drifts; the floor then at z = 0)")
    c = isub.add_parser("csv", help="any logger's CSV file, described by a map (README: the map's keys)")
    c.add_argument("log", metavar="LOG.csv")
    c.add_argument("--map", required=True, metavar="MAP.yaml", help="which columns hold what, units and frames")
    _log_arguments(c)


def _add_import_euroc(sub: argparse._SubParsersAction) -> None:
    _euroc_arguments(sub.add_parser("import-euroc", help="old spelling of `import euroc`"))


def _add_generate(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("generate", help="generate data")
    gsub = s.add_subparsers(dest="what", required=True, metavar="WHAT")
    _add_generate_flight(gsub)
    _add_generate_sim(gsub)
    _add_generate_normals(gsub)
    g = gsub.add_parser("merge", help="join the folders of `generate sim --shard` runs into one dataset")
    g.add_argument("dirs", nargs="+", metavar="DIR")
    g.add_argument("--out", required=True, metavar="DIR", help="merged dataset folder (may be one of DIR)")


def _add_generate_flight(gsub: argparse._SubParsersAction) -> None:
    g = gsub.add_parser("flight", help="a flight in the EuRoC layout with sensor noise and named effects")
    g.add_argument("--vehicle", default="hex", help=VEHICLE_HELP)
    g.add_argument("--effects", default="none", help="NAME:param=value,... from effects.md (default none)")
    g.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    g.add_argument("--kind", default="mixed", choices=["excitation", "low_passes", "mixed", "euroc_room"],
                   help="flight plan; euroc_room: a stand-in for EuRoC's Vicon-room flights with cam0")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--noise", default="realistic", choices=["realistic", "none"])
    g.add_argument("--out", required=True, help="recording folder to create")
    _add_conditions(g.add_argument_group("real recordings' troubles (truth in REC/truth.yaml)"))


def _add_conditions(group: argparse._ArgumentGroup) -> None:
    """One option per field of the conditions' schema (its help, metavar and default; a flag for a
    bool, choices where it has them, a number where it is one, the text of a pair such as VX,VY)."""
    import typing

    from uavturb.schema import option_name
    from uavturb.sim.flights.condition_schema import Conditions, condition_fields

    types = typing.get_type_hints(Conditions)
    for f in condition_fields():
        kw = {"help": f.metadata["help"], "dest": f.name}
        rule = f.metadata["allowed"]
        if types[f.name] is bool:
            group.add_argument(option_name(f.name), action="store_true", **kw)
            continue
        if f.metadata.get("metavar"):
            kw["metavar"] = f.metadata["metavar"]
        if rule.choices is not None:
            kw["choices"] = list(rule.choices)
        elif float in typing.get_args(types[f.name]) or types[f.name] is float:
            kw["type"] = float
        group.add_argument(option_name(f.name), default=f.default, **kw)  # a pair stays text: read by the schema


def _add_generate_sim(gsub: argparse._SubParsersAction) -> None:
    g = gsub.add_parser("sim", help="training shards: simulated flights through procedural scenes (resumable)")
    _later(g.add_argument("--preset", default="quick", help="%(presets)s (default quick)"), presets=_sim_presets)
    g.add_argument("--out", required=True, metavar="DIR", help="dataset folder (manifest.json, traj_*/)")
    g.add_argument("--workers", type=int, metavar="N", default=1, help="processes, one renderer each (default 1)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--shard", default=None, metavar="K/N", help="only trajectories i with i %% N == K-1 (1 <= K <= N)")
    g.add_argument("--executor", default="local", choices=["local", "ray"],
                   help="this process or --workers processes (default), or one Ray task per trajectory")
    g.add_argument("--address", default=None, help="Ray cluster for --executor ray (default: a local Ray "
                                                    "instance with --workers CPUs)")
    _add_preset_overrides(g, "width=64 trajectories=4")


def _add_generate_normals(gsub: argparse._SubParsersAction) -> None:
    g = gsub.add_parser("normals", help="depth/normal pre-training pairs from training scenes, or from IRS")
    _later(g.add_argument("--preset", default="quick", help="%(presets)s (default quick)"), presets=_sim_presets)
    g.add_argument("--out", required=True, metavar="DIR", help="dataset folder (the pairs go to DIR/pairs)")
    g.add_argument("--workers", type=int, metavar="N", default=1)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--irs", default=None, metavar="IRS_DIR", help="convert the IRS dataset instead of rendering")
    g.add_argument("--size", type=int, metavar="N", default=128, help="image side for --irs (default 128)")
    _add_preset_overrides(g, "width=64 pairs=200")


def _add_preset_overrides(g: argparse.ArgumentParser, example: str) -> None:
    """``KEY=VALUE`` preset fields, as ``train``'s overrides; ``--set KEY=VALUE`` is the same thing."""
    g.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help=f"change preset fields, e.g. {example} (dotted keys reach into mappings: "
                        "effects.ground_effect.mu=2)")
    g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="preset_set",
                   help="alias of a KEY=VALUE override (repeatable)")


def _add_gap(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("gap", help="sim-to-real gap finder: locate, name, fit and apply the physics left out")
    s.add_argument("recordings", nargs="+", metavar="REC", help="recording folders (recordings.md layout)")
    s.add_argument("--out", required=True, metavar="DIR", help="report folder (report.json, report.md, plots)")
    s.add_argument("--sim-effects", default=None, metavar="NAMES",
                   help="comma-separated effects the simulator already models, or 'none' "
                        "(default: conf/physics/default.yaml's, i.e. ground_effect)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--apply", metavar="CONF", help="write a simulator physics config with the fitted effects")
    s.add_argument("--physics-config", metavar="CONF", help="the simulator's physics config (effect parameters)")
    s.add_argument("--vehicle", help=f"{VEHICLE_HELP} for folders without one (raw EuRoC)")
    s.add_argument("--no-mlflow", action="store_true", help="do not log the run to MLflow")
    s.add_argument("--overwrite", action="store_true", help="replace a report folder that uavturb wrote")
    s.add_argument("--height-uncertainty", type=float, default=0.01, metavar="M",
                   help="how well the rotor plane's height over the floor is known [m] (default 0.01): "
                        "widens surface laws' stated errors")


def _add_gap_proof(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("gap-proof", help="run the gap finder blind on flights with concealed effects; "
                                         "print the confusion table against PySINDy")
    s.add_argument("--out", default="gap_proof", help="folder for the flights and the table (default gap_proof)")
    s.add_argument("--duration", type=float, default=90.0, help="seconds per flight (default 90)")
    s.add_argument("--effects", default=None, help="comma-separated single-effect cases (default: all)")
    s.add_argument("--no-pairs", action="store_true", help="leave out the pair cases")
    s.add_argument("--suite", default="all", choices=["all", "concealed", "conditions"],
                   help="concealed effects, real recordings' troubles (conditions), or both (default)")
    s.add_argument("--seed", type=int, default=0)


CONFIG_DIR_HELP = ("your own config folder, laid out like the shipped one (config.yaml, model/, data/, "
                   "trainer/, experiment/); its files replace or add to the shipped ones")


def _add_train(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("train", help="train one stage (pretrain or height) from conf/ with key=value overrides")
    s.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="e.g. model=none_gru trainer.max_epochs=3")
    s.add_argument("--experiment", help="a config bundle, conf/experiment/NAME.yaml (e.g. smoke)")
    s.add_argument("--resume", metavar="RUN_ID", help="continue an interrupted (or finished) run in the same MLflow "
                                                      "run from its last.ckpt; alone or with trainer.max_epochs=N, "
                                                      "the run's own config is used")
    s.add_argument("--config-dir", metavar="DIR", help=CONFIG_DIR_HELP)


def _add_sweep(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("sweep", help="run an ablation sweep (sweeps/ablation.yaml: the paper's Table 1) in MLflow")
    s.add_argument("spec", metavar="SWEEP", help="a sweep file, or a shipped sweep's name (ablation)")
    _later(s.add_argument("--profile", "--preset", dest="profile", default="quick", metavar="PROFILE",
                          help="how the sweep runs: a profile of the sweep file (ablation: %(profiles)s; default "
                               "quick): seeds and overrides, not a dataset preset; --preset is its old spelling"),
           profiles=_sweep_profiles)
    s.add_argument("--seeds", type=int, help="number of seeds (default: the profile's)")
    _add_mlflow_experiment(s)
    s.add_argument("--config-dir", metavar="DIR", help=CONFIG_DIR_HELP)
    s.add_argument("--executor", default="sequential", choices=["sequential", "ray"],
                   help="run the runs one after another here (default) or as Ray tasks")
    s.add_argument("--address", default=None, help="Ray cluster to use with --executor ray (e.g. auto, "
                                                    "ray://head:10001; default: a local Ray instance)")
    s.add_argument("--max-retries", type=int, default=1, help="extra attempts of a run that fails (default 1)")
    s.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides for every run")


def _add_compare(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("compare", help="print Table 1 (mean +- std over seeds) from the MLflow store")
    _add_mlflow_experiment(s)
    s.add_argument("--parent", default=None, metavar="RUN_ID", help="sweep parent run (default: the latest)")
    s.add_argument("--out", default="outputs", metavar="DIR", help="folder for table1.md and table1.csv")
    s.add_argument("--overwrite", action="store_true", help="replace table1.md and table1.csv there")


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("evaluate", help="Table 2: the height model and the ground-effect law on EuRoC-layout flights")
    s.add_argument("recordings", nargs="+", metavar="REC", help="recording folders; the first identifies (alpha, beta)")
    s.add_argument("--run", action="append", metavar="RUN_ID",
                   help="MLflow run of a height training (repeat for several: Table 2 over seeds)")
    s.add_argument("--sweep", metavar="PARENT_RUN_ID", help="every finished height run of this ablation sweep")
    s.add_argument("--rows",
                   help="with --sweep: only these rows, comma-separated (e.g. depth/finetune,normals/finetune)")
    s.add_argument("--out", default="evaluation", metavar="DIR", help="folder for table.md/csv and plots")
    s.add_argument("--vehicle", help=f"{VEHICLE_HELP} for folders without one (raw EuRoC)")
    s.add_argument("--frame-dt", type=float, default=None, help="frame period [s] without cam0 frames (0.05)")
    s.add_argument("--ge-fraction", type=float, default=0.01,
                   help="ground-effect frames: where the law is at least this share of the thrust (0.01)")
    s.add_argument("--no-mlflow", action="store_true", help="do not log a child run")
    s.add_argument("--overwrite", action="store_true", help="replace an output folder that uavturb wrote")


def _add_export(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("export", help="the run's model as a streaming .pt2 and ONNX, checked and logged to MLflow")
    s.add_argument("--run", required=True, metavar="RUN_ID", help="MLflow run of a height training")
    s.add_argument("--out", required=True, metavar="DIR", help="output folder (model.pt2, model.onnx, export.json)")
    s.add_argument("--data", help="shard dataset for the check (default: the run's data.root)")
    s.add_argument("--alpha", type=float, help="ground-effect law of the exported f_a (default: the model's), "
                                                "e.g. identified by `uavturb evaluate` (evaluation.json)")
    s.add_argument("--beta", type=float, help="see --alpha [m^2]")
    s.add_argument("--overwrite", action="store_true", help="replace an output folder that uavturb wrote")
    s.add_argument("--no-mlflow", action="store_true", help="do not log the model to the run")


def _add_bench(sub: argparse._SubParsersAction) -> None:
    from uavturb.bench.targets import TARGETS

    s = sub.add_parser("bench", help="benchmarks that print figures", formatter_class=argparse.RawTextHelpFormatter,
                       epilog="targets:\n" + "\n".join(f"  {k:<10}{v}" for k, v in TARGETS.items()))
    s.add_argument("what", choices=list(TARGETS), metavar="TARGET", help=" | ".join(TARGETS))
    gp = s.add_argument_group("TARGET gap")
    gp.add_argument("recordings", nargs="*", metavar="REC",
                    help="recordings to analyse (default: two generated flights)")
    gp.add_argument("--minutes", type=float, help="length of each generated flight (default 5)")
    gp.add_argument("--measured-hour", action=argparse.BooleanOptionalAction, default=None,
                    help="also measure an hour whole: the recordings repeated to an hour of flight, one "
                         "recording each repeat (default: on)")
    g = s.add_argument_group("TARGET gpu")
    g.add_argument("--device", choices=["cuda", "cpu"], help="cuda (default; refused where none is seen) or cpu "
                                                             "(the same measurement, small)")
    g.add_argument("--size", type=int, metavar="N", help="image side in px (default 128 on cuda, 32 on cpu)")
    g.add_argument("--batch-size", type=int, metavar="N", help="windows or pairs per batch (default 16)")
    g.add_argument("--workers", type=int, metavar="N", help="DataLoader workers (default data=shards_gpu's; 0 on cpu)")
    g.add_argument("--steps", type=int, metavar="N", help="timed batches per epoch (default 100 on cuda, 4 on cpu)")
    g.add_argument("--epochs", type=int, metavar="N", help="epochs per measurement, the first one warm-up (default 3)")
    g.add_argument("--precision", dest="precisions", type=lambda x: tuple(x.split(",")), metavar="P[,P...]",
                   help="trainer.precision values, comma-separated (default 32-true,bf16-mixed)")
    g.add_argument("--cpu-threads", type=int, metavar="N", help="torch threads of the CPU reference (default 2)")


def _add_demo(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("demo", help="the main job, end to end, on data the project generates")
    s.add_argument("--out", default="demo_out")
    s.add_argument("--seed", type=int, default=0)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uavturb", description=__doc__.split("\n")[0] if __doc__ else None)
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_add_identify, _add_residuals, _add_import, _add_import_euroc, _add_generate, _add_gap, _add_gap_proof,
                _add_train, _add_sweep, _add_compare, _add_evaluate, _add_export, _add_bench, _add_demo):
        add(sub)  # in this order in --help
    return p


def _negative_values_attached(argv: list[str]) -> list[str]:
    """``--floor-z -inf`` as ``--floor-z=-inf``: argparse reads a value that starts with ``-`` and is not a plain
    decimal (``-inf``, ``-1e3``, ``-1,2``) as an option, and stops with "expected one argument"."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and arg.startswith("-") and _is_numbers(arg):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def _is_numbers(text: str) -> bool:
    """Whether ``text`` is one number or numbers separated by commas (``-1e3``, ``-inf``, ``-1.5,2``)."""
    try:
        [float(x) for x in text.split(",")]
    except ValueError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    os.environ.setdefault("MPLBACKEND", "Agg")
    parser = _parser()
    args, extra = parser.parse_known_args(_negative_values_attached(sys.argv[1:] if argv is None else list(argv)))
    if extra:  # key=value overrides given after options (train, sweep, generate sim|normals): argparse leaves them over
        if hasattr(args, "overrides") and all("=" in x and not x.startswith("-") for x in extra):
            args.overrides = [*args.overrides, *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    name = f"import {args.what}" if args.command == "import" else args.command
    try:
        with raise_on_signals():  # SIGTERM (kill, scancel, time limits), SIGINT: clean up, one line, 128 + signum
            return _run(args)
    except UavturbError as e:
        print(f"uavturb {name}: error: {e}", file=sys.stderr)
        return 2
    except Interrupted as e:
        print(f"uavturb {name}: {e.message()}", file=sys.stderr, flush=True)
        return e.exit_status
    except KeyboardInterrupt:
        print(f"uavturb {name}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError as e:
        if not _reader_gone(sys.stdout):  # another pipe (a child process's): the last guard's line
            line, code = _last_guard(e)
            print(f"uavturb {args.command}: error: {line}", file=sys.stderr)
            return code
        # whoever read stdout stopped (``uavturb gap ... | head -1``): what was to be written is written; stop
        # quietly, as a command killed by SIGPIPE does, and keep the interpreter's exit from flushing into the pipe
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + 13
    except Exception as e:  # noqa: BLE001 - the last guard: one line, never a traceback
        if os.environ.get("UAVTURB_TRACEBACK"):
            raise
        line, code = _last_guard(e)
        print(f"uavturb {args.command}: error: {line}", file=sys.stderr)
        return code


def _reader_gone(stream) -> bool:
    """Whether ``stream`` is a pipe whose reading end has been closed (poll reports an error on it)."""
    import select

    try:
        poll = select.poll()
        poll.register(stream.fileno(), select.POLLOUT)
        return any(event & (select.POLLERR | select.POLLHUP) for _, event in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # no fileno (a test's capture), or no poll on this system
        return False


def _os_error_file(e: OSError, at: str) -> str:
    """The file an OSError is about: its name (``SRC -> DST`` for a rename or copy) where Python knows it, otherwise
    where it was opened (``at``: `` at FILE:LINE``, the innermost frame)."""
    if e.filename is None:
        return f"a file opened{at}" if at else "a file"
    return f"{e.filename} -> {e.filename2}" if e.filename2 is not None else str(e.filename)


def _last_guard(e: Exception) -> tuple[str, int]:
    """The one line (and exit status) of an error no library function turned into an InputError:
    2 for what the machine or the input ran into, 1 for a defect of uavturb (with where it happened)."""
    import errno
    import traceback

    from uavturb.errors import shorten

    if isinstance(e, MemoryError):
        return "out of memory: an input (or the work it asks for) is larger than this machine can hold", 2
    if isinstance(e, RecursionError):
        return "an input is nested too deeply to be read", 2
    if isinstance(e, UnicodeDecodeError):
        return shorten(f"an input is not UTF-8 text ({e.reason} at byte {e.start})", 300), 2
    frame = traceback.extract_tb(e.__traceback__)[-1] if e.__traceback__ else None
    at = f" at {Path(frame.filename).name}:{frame.lineno}" if frame else ""
    if isinstance(e, OSError):
        where = _os_error_file(e, at)
        if e.errno == errno.ENOSPC:
            return shorten(f"{where}: no space left on the device; free some space and run the command again", 400), 2
        if e.filename is None and e.strerror is None and str(e):  # raised with a message only, which may name it
            return shorten(f"{e} ({type(e).__name__}{at})", 400), 2  # Lightning: "Checkpoint file not found: PATH"
        return shorten(f"{where}: {e.strerror or type(e).__name__}", 400), 2
    return shorten(f"internal error ({type(e).__name__}: {e}){at}; set UAVTURB_TRACEBACK=1 to see the traceback "
                   "and please report it", 600), 1


# --- one handler a command: calls one library function and prints what it returns ----------------


def _identify(args: argparse.Namespace) -> int:
    from uavturb.commands.identify import format_identification, identify_recordings
    from uavturb.io.strict_json import dumps_strict

    ident = identify_recordings(args.recordings, model=args.model, vehicle=args.vehicle)
    print(dumps_strict(ident.to_dict()) if args.json else format_identification(ident))
    return 0


def _residuals(args: argparse.Namespace) -> int:
    from uavturb.commands.identify import residuals_to_file

    res, path = residuals_to_file(args.recording, args.out, source=args.source, derivative=args.derivative,
                                  params=args.params, vehicle=args.vehicle, overwrite=args.overwrite)
    contact = (f" ({res.on_ground} on the ground, flagged in column ground_contact and left out of it: the floor's "
               f"reaction is in their residual)" if res.on_ground else "")
    print(f"wrote {path}: {len(res.t)} samples, source {res.source}, residual RMS in flight "
          f"{res.rmse_in_flight:.4f} N{contact}")
    return 0


def _import_euroc(args: argparse.Namespace) -> int:
    from uavturb.io.euroc_import import import_euroc

    if args.command == "import-euroc":
        print("uavturb import-euroc: deprecated spelling, use `uavturb import euroc`", file=sys.stderr)
    rec = import_euroc(args.bag, args.out, vehicle=args.vehicle, asl=args.asl,
                       rotor_speed_scale=args.rotor_speed_scale, overwrite=args.overwrite)
    print(f"wrote {args.out}: {len(rec.ground_truth.t_ns)} ground-truth rows, {len(rec.rotors.t_ns)} rotor rows, "
          f"imu {'yes' if rec.imu is not None else 'no'}, point cloud {'yes' if rec.points is not None else 'no'}")
    return 0


def _import_ulog(args: argparse.Namespace) -> int:
    from uavturb.io.ulog_import import import_ulog

    order = None
    if args.motor_order is not None:
        try:
            order = [int(x) for x in args.motor_order.split(",")]
        except ValueError:
            raise InputError("--motor-order", f"expected indices separated by commas, got {args.motor_order!r}")
    _, summary = import_ulog(args.log, args.out, vehicle=args.vehicle, motor_order=order, rotors=args.rotors,
                             thrust_map=args.thrust_map, floor_z=args.floor_z, rotor_plane_z=args.rotor_plane_z,
                             overwrite=args.overwrite, height=args.height)
    print(summary.line())
    return 0


def _import_csv(args: argparse.Namespace) -> int:
    from uavturb.io.csv_import import import_csv

    _, summary = import_csv(args.log, args.map, args.out, vehicle=args.vehicle, floor_z=args.floor_z,
                            rotor_plane_z=args.rotor_plane_z, overwrite=args.overwrite)
    print(summary.line())
    return 0


def _generate_flight(args: argparse.Namespace) -> int:
    from uavturb.commands.generate import generate_flight_command
    from uavturb.sim.flights.condition_schema import condition_fields

    rec = generate_flight_command(vehicle=args.vehicle, effects=args.effects, duration=args.duration,
                                  kind=args.kind, seed=args.seed, noise=args.noise, out=args.out,
                                  **{f.name: getattr(args, f.name) for f in condition_fields()})
    gt = rec.ground_truth
    print(f"wrote {args.out}: {len(gt)} ground-truth rows, {(gt.t_ns[-1] - gt.t_ns[0]) * 1e-9:.1f} s, "
          f"effects {args.effects}")
    return 0


def _generate_sim(args: argparse.Namespace) -> int:
    from uavturb.commands.generate import generate_sim, preset_overrides

    print(generate_sim(args.preset, args.out, workers=args.workers, seed=args.seed, shard=args.shard,
                       executor=args.executor, address=args.address,
                       **preset_overrides([*args.preset_set, *args.overrides], args.preset)))
    return 0


def _generate_normals(args: argparse.Namespace) -> int:
    from uavturb.commands.generate import generate_normals, preset_overrides

    print(generate_normals(args.preset, args.out, workers=args.workers, seed=args.seed, irs=args.irs,
                           size=args.size, **preset_overrides([*args.preset_set, *args.overrides], args.preset)))
    return 0


def _generate_merge(args: argparse.Namespace) -> int:
    from uavturb.commands.generate import generate_merge

    print(generate_merge(args.dirs, args.out))
    return 0


def _gap(args: argparse.Namespace) -> int:
    from uavturb.commands.gap import gap
    from uavturb.gap.report import format_effect

    report = gap(args.recordings, args.out, sim_effects=args.sim_effects, seed=args.seed, apply=args.apply,
                 vehicle=args.vehicle, log_mlflow=not args.no_mlflow, physics_config=args.physics_config,
                 overwrite=args.overwrite, height_uncertainty=args.height_uncertainty)
    print(f"effects named: {', '.join(format_effect(e) for e in report['effects']) or 'none'}")
    print(f"held-out residual RMSE {report['baseline']['heldout_rmse_N']:.4f} N -> "
          f"{report['final']['heldout_rmse_N']:.4f} N ({report['protocol']}); report in {args.out}")
    offset = (report.get("height_reference") or {}).get("offset_read_from_curve")
    if offset:
        print(f"heights off? {offset['why']}")
    return 0


def _gap_proof(args: argparse.Namespace) -> int:
    from uavturb.proof.gap_proof import gap_proof

    gap_proof(Path(args.out), duration=args.duration, seed=args.seed,
              singles=args.effects.split(",") if args.effects else None, pairs=not args.no_pairs, suite=args.suite)
    return 0


def _train(args: argparse.Namespace) -> int:
    from uavturb.runs.config import load_config
    from uavturb.runs.resume import resume_config
    from uavturb.runs.train import train

    if args.resume:
        out = train(resume_config(args.resume, args.overrides, args.experiment), resume=args.resume)
    else:
        out = train(load_config(args.overrides, experiment=args.experiment, conf_dir=args.config_dir))
    if out.get("global_rank", 0) != 0:  # DDP: the other ranks say nothing
        return 0
    print(json.dumps({k: out[k] for k in ("stage", "run_id", "checkpoint", "data_hash", "start_epoch")}))
    print("  ".join(f"{k} {v:.5g}" for k, v in sorted(out["metrics"].items()) if k.startswith("test/")))
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from uavturb.runs.sweep import sweep

    res = sweep(args.spec, profile=args.profile, seeds=args.seeds, overrides=args.overrides,
                experiment=args.mlflow_experiment, conf_dir=args.config_dir, executor=args.executor,
                address=args.address, max_retries=args.max_retries)
    print(res["table"])
    return 0


def _compare(args: argparse.Namespace) -> int:
    from uavturb.runs.table1 import compare

    res = compare(experiment=args.mlflow_experiment, parent_run_id=args.parent, out=args.out,
                  overwrite=args.overwrite)
    print(res["table"])
    print(f"wrote {res['markdown']} and {res['csv']}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from uavturb.commands.evaluate import evaluate, evaluate_runs, sweep_runs

    if (args.sweep is None) == (args.run is None):
        raise InputError("--run", "give one or more --run RUN_ID, or --sweep PARENT_RUN_ID")
    if args.rows is not None and args.sweep is None:
        raise InputError("--rows", "selects rows of a --sweep")
    if args.sweep is None and len(args.run) == 1:
        evaluate(args.run[0], args.recordings, out=args.out, vehicle=args.vehicle, frame_dt=args.frame_dt,
                 ge_fraction=args.ge_fraction, log=not args.no_mlflow, overwrite=args.overwrite)
        return 0
    runs = args.run if args.sweep is None else sweep_runs(args.sweep, args.rows.split(",") if args.rows else None)
    evaluate_runs(runs, args.recordings, out=args.out, vehicle=args.vehicle, frame_dt=args.frame_dt,
                  ge_fraction=args.ge_fraction, log=not args.no_mlflow, overwrite=args.overwrite)
    return 0


def _export(args: argparse.Namespace) -> int:
    from uavturb.commands.export import export

    res = export(args.run, args.out, data=args.data, alpha=args.alpha, beta=args.beta, overwrite=args.overwrite,
                 log=not args.no_mlflow)
    print(f"wrote {res['out']}: model.pt2, model.onnx (max abs difference {res['max_abs_diff']:.3g})")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from uavturb.bench.targets import BENCH_OPTIONS, bench_target

    bench_target(args.what, {k: getattr(args, k) for k in BENCH_OPTIONS})
    return 0


def _demo(args: argparse.Namespace) -> int:
    from uavturb.commands.demo import run

    run(Path(args.out), seed=args.seed)
    return 0


#: command (and ``generate``'s WHAT) -> its handler
HANDLERS: dict[str, Callable[[argparse.Namespace], int]] = {
    "identify": _identify, "residuals": _residuals, "import-euroc": _import_euroc, "import euroc": _import_euroc,
    "import ulog": _import_ulog, "import csv": _import_csv,
    "generate flight": _generate_flight, "generate sim": _generate_sim, "generate normals": _generate_normals,
    "generate merge": _generate_merge, "gap": _gap, "gap-proof": _gap_proof, "train": _train, "sweep": _sweep,
    "compare": _compare, "evaluate": _evaluate, "export": _export, "bench": _bench, "demo": _demo,
}


def _run(args: argparse.Namespace) -> int:
    command = f"{args.command} {args.what}" if args.command in ("generate", "import") else args.command
    return HANDLERS[command](args)


#: commands that leave nothing for the interpreter's exit to do (each process they start is waited for, each file
#: they write closed, no logging handler or background writer left): the program ends without its teardown, which
#: after ``uavturb gap`` spent 0.2-0.3 s freeing the modules of numpy, scipy, pandas and matplotlib (six walks: the
#: whole command 9.06 s on average against 8.85 s, three runs each in turn)
QUICK_EXIT = frozenset({"gap"})


def console() -> None:
    """The ``uavturb`` program (pyproject's script, ``python -m uavturb.cli``): :func:`main` on the command line, then
    the process ends with its exit status; after the commands of :data:`QUICK_EXIT` (named first on the command line)
    at once, its output flushed, as ``runs.store_process`` ends. Tests call :func:`main`, which returns."""
    argv = sys.argv[1:]
    code = main(argv)
    if not argv or argv[0] not in QUICK_EXIT:
        sys.exit(code)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a reader gone (main has already said what it had to), a stream closed
            pass
    os._exit(code & 0xFF)


if __name__ == "__main__":
    console()
