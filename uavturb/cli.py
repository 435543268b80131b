"""The ``uavturb`` command: parses arguments and calls library functions, nothing more."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from uavturb.errors import UavturbError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uavturb", description=__doc__.split("\n")[0] if __doc__ else None)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("identify", help="identify k_T, k_M and inertia from flights (the paper's least squares)")
    s.add_argument("recordings", nargs="+", metavar="REC", help="recording folders (recordings.md layout)")
    s.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    s.add_argument("--model", default="auto", choices=["auto", "general", "jx=jy"],
                   help="inertia model: J_x != J_y, the paper's J_x = J_y, or chosen by the data (default)")
    s.add_argument("--vehicle", help="vehicle.yaml or preset (quad, hex) for folders without one (raw EuRoC)")

    s = sub.add_parser("residuals", help="ground-truth turbulence: residual force of the identified model")
    s.add_argument("recording", metavar="REC")
    s.add_argument("--out", required=True, help="output file: .csv or .parquet")
    s.add_argument("--source", default="auto", choices=["auto", "imu", "mocap"],
                   help="IMU specific force (default where present) or differentiated MoCap velocity")
    s.add_argument("--derivative", default="savgol", choices=["savgol", "forward"],
                   help="MoCap derivative: Savitzky-Golay or the paper's one-step forward difference")
    s.add_argument("--params", default="identified", choices=["identified", "nominal"],
                   help="model constants: identified on this flight (default) or vehicle.yaml's")
    s.add_argument("--vehicle", help="vehicle.yaml or preset for folders without one")

    s = sub.add_parser("generate", help="generate data")
    gsub = s.add_subparsers(dest="what", required=True, metavar="WHAT")
    g = gsub.add_parser("flight", help="a flight in the EuRoC layout with sensor noise and named effects")
    g.add_argument("--vehicle", default="hex", help="preset (quad, hex) or vehicle.yaml")
    g.add_argument("--effects", default="none", help="NAME:param=value,... from effects.md (default none)")
    g.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    g.add_argument("--kind", default="mixed", choices=["excitation", "low_passes", "mixed"])
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--noise", default="realistic", choices=["realistic", "none"])
    g.add_argument("--out", required=True, help="recording folder to create")

    s = sub.add_parser("gap", help="sim-to-real gap finder: locate, name, fit and apply the physics left out")
    s.add_argument("recordings", nargs="+", metavar="REC", help="recording folders (recordings.md layout)")
    s.add_argument("--out", required=True, metavar="DIR", help="report folder (report.json, report.md, plots)")
    s.add_argument("--sim-effects", default=None, metavar="NAMES",
                   help="comma-separated effects the simulator already models, or 'none' "
                        "(default: conf/physics/default.yaml's, i.e. ground_effect)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--apply", metavar="CONF", help="write a simulator physics config with the fitted effects")
    s.add_argument("--physics-config", metavar="CONF", help="the simulator's physics config (effect parameters)")
    s.add_argument("--vehicle", help="vehicle.yaml or preset for folders without one (raw EuRoC)")
    s.add_argument("--no-mlflow", action="store_true", help="do not log the run to MLflow")

    s = sub.add_parser("gap-proof", help="run the gap finder blind on flights with concealed effects; "
                                         "print the confusion table against PySINDy")
    s.add_argument("--out", default="gap_proof", help="folder for the flights and the table (default gap_proof)")
    s.add_argument("--duration", type=float, default=90.0, help="seconds per flight (default 90)")
    s.add_argument("--effects", default=None, help="comma-separated single-effect cases (default: all)")
    s.add_argument("--no-pairs", action="store_true", help="leave out the pair cases")
    s.add_argument("--seed", type=int, default=0)

    s = sub.add_parser("train", help="train one stage (pretrain or height) from conf/ with key=value overrides")
    s.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="e.g. model=none_gru trainer.max_epochs=3")
    s.add_argument("--experiment", help="a conf/experiment/*.yaml bundle (e.g. smoke)")

    s = sub.add_parser("sweep", help="run an ablation sweep (sweeps/ablation.yaml: the paper's Table 1) in MLflow")
    s.add_argument("spec", metavar="SWEEP.yaml")
    s.add_argument("--preset", default="quick", help="preset of the sweep file (quick, paper; default quick)")
    s.add_argument("--seeds", type=int, help="number of seeds (default: the preset's)")
    s.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides for every run")

    s = sub.add_parser("compare", help="print Table 1 (mean +- std over seeds) from the MLflow store")
    s.add_argument("--experiment", default=None, help="MLflow experiment (default: the sweep file's)")
    s.add_argument("--parent", default=None, metavar="RUN_ID", help="sweep parent run (default: the latest)")
    s.add_argument("--out", default="outputs", metavar="DIR", help="folder for table1.md and table1.csv")

    s = sub.add_parser("bench", help="benchmarks that print figures")
    s.add_argument("what", choices=["scene", "physics", "gap"])

    s = sub.add_parser("demo", help="the main job, end to end, on data the project generates")
    s.add_argument("--out", default="demo_out")
    s.add_argument("--seed", type=int, default=0)
    return p


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    os.environ.setdefault("MPLBACKEND", "Agg")
    args = _parser().parse_args(argv)
    try:
        return _run(args)
    except UavturbError as e:
        print(f"uavturb {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"uavturb {args.command}: interrupted", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    from uavturb import workflows

    if args.command == "identify":
        ident = workflows.identify_recordings(args.recordings, model=args.model, vehicle=args.vehicle)
        if args.json:
            print(json.dumps(ident.to_dict()))
        else:
            print(workflows.format_identification(ident))
    elif args.command == "residuals":
        res, path = workflows.residuals_to_file(args.recording, args.out, source=args.source,
                                                derivative=args.derivative, params=args.params,
                                                vehicle=args.vehicle)
        print(f"wrote {path}: {len(res.t)} samples, source {res.source}, residual RMS {res.rmse:.4f} N")
    elif args.command == "generate":
        if args.what == "flight":
            rec = workflows.generate_flight(vehicle=args.vehicle, effects=args.effects, duration=args.duration,
                                            kind=args.kind, seed=args.seed, noise=args.noise, out=args.out)
            gt = rec.ground_truth
            print(f"wrote {args.out}: {len(gt)} ground-truth rows, {(gt.t_ns[-1] - gt.t_ns[0]) * 1e-9:.1f} s, "
                  f"effects {args.effects}")
    elif args.command == "gap":
        from uavturb.gap.finder import gap

        report = gap(args.recordings, args.out, sim_effects=args.sim_effects, seed=args.seed, apply=args.apply,
                     vehicle=args.vehicle, log_mlflow=not args.no_mlflow, physics_config=args.physics_config)
        named = ", ".join(f"{e['name']} {e['params']}" for e in report["effects"]) or "none"
        print(f"effects named: {named}")
        print(f"held-out residual RMSE {report['baseline']['heldout_rmse_N']:.4f} N -> "
              f"{report['final']['heldout_rmse_N']:.4f} N ({report['protocol']}); report in {args.out}")
    elif args.command == "gap-proof":
        workflows.gap_proof(Path(args.out), duration=args.duration, seed=args.seed,
                            singles=args.effects.split(",") if args.effects else None, pairs=not args.no_pairs)
    elif args.command == "train":
        from uavturb.config import load_config
        from uavturb.train import train

        out = train(load_config(args.overrides, experiment=args.experiment))
        print(json.dumps({k: out[k] for k in ("stage", "run_id", "checkpoint", "data_hash")}))
        print("  ".join(f"{k} {v:.5g}" for k, v in sorted(out["metrics"].items()) if k.startswith("test/")))
    elif args.command == "sweep":
        from uavturb.sweep import sweep

        res = sweep(args.spec, preset=args.preset, seeds=args.seeds, overrides=args.overrides)
        print(res["table"])
    elif args.command == "compare":
        from uavturb.compare import compare

        res = compare(experiment=args.experiment, parent_run_id=args.parent, out=args.out)
        print(res["table"])
        print(f"wrote {res['markdown']} and {res['csv']}")
    elif args.command == "bench":
        workflows.bench(args.what)
    elif args.command == "demo":
        workflows.demo(Path(args.out), seed=args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
