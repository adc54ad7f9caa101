"""`membrane train`, `membrane export` and `membrane evaluate`.

This module imports with the core dependencies only; torch, onnxruntime and the rest are imported
inside the handlers (the dispatcher turns a missing one into "install membrane-tissue[extra]").
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import sys
from pathlib import Path
from typing import Any

from membrane_cli.arguments import UsageError
from membrane_models.commands.exact import parse_assignments
from membrane_models.executors import add_executor_arguments

__all__ = ["add_evaluate", "add_export", "add_train", "train_command"]

logger = logging.getLogger(__name__)


# ---------------------------------------------------------------- train


def add_train(subparsers: argparse._SubParsersAction) -> None:
    """Register `membrane train`."""
    parser = subparsers.add_parser(
        "train",
        help="train a physics-informed network for a problem",
        description=(
            "Train a separable physics-informed network (PDE residual only; boundary and initial "
            "conditions exact by construction) and write OUT/checkpoint.pt and OUT/train.log."
        ),
    )
    parser.add_argument(
        "problem",
        help="problem name (string-forced, membrane-forced, ...) or koopman-string (the Koopman "
        "latent model, trained on a `membrane data koopman-string` dataset given by --data)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--arch",
        default="spinn",
        help="spinn (ours) or stmsffn (the published configuration); for koopman-string: aux "
        "(frequencies from an auxiliary network, default) or fixed (a fixed spectrum)",
    )
    parser.add_argument(
        "--data", type=Path, help="koopman-string only: the dataset folder (train.npz, ...)"
    )
    parser.add_argument("--iterations", type=int, help="total iterations (default: the recipe's)")
    parser.add_argument(
        "--lbfgs-fraction", type=float, help="share of iterations done by L-BFGS at the end"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a problem parameter (repeatable), e.g. --set c=8",
    )
    parser.add_argument("--resume", action="store_true", help="continue OUT/checkpoint.pt")
    parser.add_argument(
        "--monitor-every",
        type=int,
        default=0,
        metavar="N",
        help="log the error against the exact solution every N iterations (0: never)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--seeds",
        help="a sweep: one run per seed (0,1,2 or 0-3), each in OUT/seed-N (OUT/sweep.json "
        "lists their final losses)",
    )
    parser.add_argument(
        "--sweep",
        action="append",
        default=[],
        metavar="NAME=V1,V2",
        help="a sweep over a problem parameter (repeatable: their product), each run in "
        "OUT/NAME=V,seed-N",
    )
    add_executor_arguments(parser)
    parser.set_defaults(handler=_run_train)


def train_command(args: argparse.Namespace) -> str:
    """The canonical command line of a training run (stored in checkpoints and manifests)."""
    parts = ["membrane", "train", args.problem, "--arch", args.arch]
    if args.iterations is not None:
        parts += ["--iterations", str(args.iterations)]
    if args.lbfgs_fraction is not None:
        parts += ["--lbfgs-fraction", str(args.lbfgs_fraction)]
    parts += ["--seed", str(args.seed)]
    for item in args.sets:
        parts += ["--set", item]
    parts += ["--out", str(args.out)]
    return shlex.join(parts)


def _run_train(args: argparse.Namespace) -> int:
    from membrane_models.commands.koopman import KOOPMAN_MODEL, run_koopman_train

    if args.problem == KOOPMAN_MODEL:
        return run_koopman_train(args)
    if args.data is not None:
        raise UsageError(f"--data is for {KOOPMAN_MODEL} only")
    if args.seeds is not None or args.sweep:
        return _run_sweep(args)
    if args.executor is not None or args.ray_address is not None or args.workers is not None:
        raise UsageError(
            "--executor, --ray-address and --workers are for sweeps (--seeds, --sweep)"
        )
    import torch

    from membrane_models.learned.training import recipe, train

    changes: dict[str, Any] = {"seed": args.seed, "overrides": parse_assignments(args.sets)}
    if args.iterations is not None:
        if args.iterations <= 0:
            raise UsageError(f"--iterations must be > 0, got {args.iterations}")
        changes["iterations"] = args.iterations
    if args.lbfgs_fraction is not None:
        if not 0.0 <= args.lbfgs_fraction < 1.0:
            raise UsageError(f"--lbfgs-fraction must be in [0, 1), got {args.lbfgs_fraction}")
        changes["lbfgs_fraction"] = args.lbfgs_fraction
    if args.monitor_every < 0:
        raise UsageError("--monitor-every must be >= 0")
    changes["monitor_every"] = args.monitor_every
    config = recipe(args.problem, args.arch, **changes)
    from membrane_models.learned.training import build_model

    build_model(config)  # validates the problem and its overrides before any file is written
    args.out.mkdir(parents=True, exist_ok=True)
    log_handler = logging.FileHandler(args.out / "train.log")
    log_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    train_logger = logging.getLogger("membrane_models")
    train_logger.addHandler(log_handler)
    train_logger.setLevel(logging.INFO)
    # The log file gets every record; the terminal shows the progress bar (and logs with -v).
    propagate = train_logger.propagate
    train_logger.propagate = getattr(args, "verbose", 0) > 0
    # One thread: the per-axis networks are small, and on a shared CPU a second intra-op thread
    # costs more in waiting than it gains.
    torch.set_num_threads(1)
    command = train_command(args)
    try:
        logger.info("command: %s", command)
        monitor = _exact_monitor(config) if args.monitor_every else None
        result = train(
            config,
            out_dir=args.out,
            command=command,
            resume=args.resume,
            monitor=monitor,
            progress=not args.no_progress,
        )
    finally:
        train_logger.removeHandler(log_handler)
        train_logger.propagate = propagate
        log_handler.close()
    last = result.history[-1] if result.history else {}
    terms = " ".join(f"{k}={v:.3e}" for k, v in last.items() if k not in ("iteration", "wall_time"))
    print(f"trained {result.iterations} iterations in {result.wall_time:.1f} s: {terms}")
    print(f"checkpoint: {result.checkpoint}")
    return 0


def _run_sweep(args: argparse.Namespace) -> int:
    """Many runs (``train_sweep``): every seed of ``--seeds`` for every ``--sweep`` value."""
    from membrane_models.commands.train_sweep import (
        parse_seeds,
        parse_sweep,
        run_sweep,
        sweep_specs,
    )
    from membrane_models.executors import executor_from_args

    if args.resume or args.monitor_every:
        raise UsageError("--resume and --monitor-every are for a single run, not a sweep")
    if args.iterations is not None and args.iterations <= 0:
        raise UsageError(f"--iterations must be > 0, got {args.iterations}")
    if args.lbfgs_fraction is not None and not 0.0 <= args.lbfgs_fraction < 1.0:
        raise UsageError(f"--lbfgs-fraction must be in [0, 1), got {args.lbfgs_fraction}")
    seeds = parse_seeds(args.seeds) or [args.seed]
    base = {
        "problem": args.problem,
        "arch": args.arch,
        "iterations": args.iterations,
        "lbfgs_fraction": args.lbfgs_fraction,
        "sets": list(args.sets),
        "out": str(args.out),
    }
    specs = sweep_specs(base, seeds, parse_sweep(args.sweep))
    for spec in specs:
        run_args = argparse.Namespace(
            **{**vars(args), "seed": spec["seed"], "sets": spec["sets"], "out": Path(spec["out"])}
        )
        spec["command"] = train_command(run_args)
    return run_sweep(specs, args.out, executor_from_args(args), progress=not args.no_progress)


def _exact_monitor(config: Any) -> Any:
    """A training monitor: relative L2 error on the standard grid (torch forward, float64)."""
    import numpy as np
    import torch

    from membrane_models.artifacts.evaluate import reference_on_grid
    from membrane_models.problems import make_problem

    problem = make_problem(config.problem, config.overrides)
    points, exact = reference_on_grid(problem)
    inputs = torch.from_numpy(points)

    def monitor(model: Any) -> dict[str, float]:
        with torch.no_grad():
            dtype = next(model.parameters()).dtype
            u = model(inputs.to(dtype)).double().numpy()[:, 0]
        return {"rel_l2": float(np.linalg.norm(u - exact) / np.linalg.norm(exact))}

    return monitor


# ---------------------------------------------------------------- export


def add_export(subparsers: argparse._SubParsersAction) -> None:
    """Register `membrane export`."""
    parser = subparsers.add_parser(
        "export",
        help="export a checkpoint to ONNX graphs and a manifest",
        description=(
            "Write MODEL.onnx (full graph), MODEL.space.onnx and MODEL.time.onnx (separable "
            "parts) and MODEL.json (manifest, with the error measured against the exact "
            "solution). Checks torch-vs-onnxruntime parity and fails if it does not hold."
        ),
    )
    parser.add_argument("checkpoint", type=Path, help="checkpoint.pt written by `membrane train`")
    parser.add_argument("--out", type=Path, required=True, help="MODEL.onnx to write")
    parser.add_argument(
        "--data",
        type=Path,
        help="Koopman checkpoints: the dataset whose test split the manifest's error table is "
        "measured on (default: the one it was trained from)",
    )
    parser.set_defaults(handler=_run_export)


def _run_export(args: argparse.Namespace) -> int:
    from membrane_models.commands.koopman import is_koopman_checkpoint, run_koopman_export
    from membrane_models.learned.export import ParityError, export_checkpoint

    if is_koopman_checkpoint(args.checkpoint):
        try:
            return run_koopman_export(args)
        except ParityError as exc:
            print(f"membrane export: parity check failed: {exc}", file=sys.stderr)
            return 1

    if args.out.suffix != ".onnx" or args.out.name.endswith((".space.onnx", ".time.onnx")):
        raise UsageError(f"--out must be MODEL.onnx, got {args.out}")
    try:
        manifest = export_checkpoint(args.checkpoint, args.out)
    except ParityError as exc:
        print(f"membrane export: parity check failed: {exc}", file=sys.stderr)
        return 1
    error = manifest.error
    print(
        f"wrote {args.out} (+ space/time graphs, {manifest.name}.json): relative L2 "
        f"{error['relative_l2']:.3e}, max abs {error['max_abs']:.3e}"
    )
    return 0


# ---------------------------------------------------------------- evaluate


def add_evaluate(subparsers: argparse._SubParsersAction) -> None:
    """Register `membrane evaluate`."""
    parser = subparsers.add_parser(
        "evaluate",
        help="measure a model's error against the exact solution",
        description=(
            "Relative L2 and max-abs error of a model (zoo name, MODEL.onnx or MODEL.json) "
            "against the exact solution on the standard grid (string 101x101 in x,t; membrane "
            "41x41x101), computed with onnxruntime."
        ),
    )
    parser.add_argument("model", help="zoo name or path to MODEL.onnx / MODEL.json")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--plot", type=Path, metavar="FILE.png", help="predicted | exact | error")
    parser.add_argument(
        "--data",
        type=Path,
        help="Koopman models: re-measure the error table on this dataset's test split "
        "(default: print the manifest's)",
    )
    parser.set_defaults(handler=_run_evaluate)


def _run_evaluate(args: argparse.Namespace) -> int:
    from membrane_models.artifacts.evaluate import evaluate_model, plot_comparison
    from membrane_models.artifacts.koopman_manifest import find_koopman_model
    from membrane_models.artifacts.zoo_index import resolve_model
    from membrane_models.commands.koopman import run_koopman_evaluate

    koopman = find_koopman_model(args.model)
    if koopman is not None:
        return run_koopman_evaluate(args, koopman)

    manifest = resolve_model(args.model)
    report = evaluate_model(manifest)
    if args.plot is not None:
        plot_comparison(report, args.plot)
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        print(
            f"{manifest.name} ({manifest.problem}): relative L2 {report.relative_l2:.3e}, "
            f"max abs {report.max_abs:.3e} on {report.grid_text()}"
        )
        if args.plot is not None:
            print(f"plot: {args.plot}")
    return 0
