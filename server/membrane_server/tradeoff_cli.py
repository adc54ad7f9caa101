"""`membrane tradeoff`: measure every way of answering a query; write the table and the plot.

This module imports with the core dependencies only; the measurement (server, models, scipy,
onnxruntime) and the plot (matplotlib) are imported when the command runs.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from membrane_cli.arguments import bounded_int
from membrane_models.executors import add_executor_arguments, executor_from_args

__all__ = ["add_tradeoff"]


def add_tradeoff(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane tradeoff`."""
    parser = subparsers.add_parser(
        "tradeoff",
        help="measure latency and error of every model, evaluator and lattice; table and plot",
        description=(
            "For each shipped model (and the exact reference) x evaluator x lattice size, and "
            "the onnxruntime knobs, serve the scene from a real server process, sweep its time "
            "grid with a real client, and record p50/p99 query latency and the relative L2 "
            "error against the exact solution. Writes a markdown table and a log-log Pareto "
            "plot. With --executor ray the cases' errors are measured in parallel first, each "
            "case served by a server of its own in a Ray task; the timings stay serial, so it "
            "saves at most the exact solution's evaluation per case (on a 2-core machine it is "
            "slower: docs/BENCHMARKS.md). Exit code 1 when no case could be measured."
        ),
    )
    # Required: a default path would overwrite whatever docs/ the current directory holds.
    parser.add_argument(
        "--out", type=Path, required=True, metavar="FILE",
        help="markdown table to write (the project's own: docs/TRADEOFF.md)",
    )  # fmt: skip
    parser.add_argument(
        "--plot", type=Path, default=None, metavar="FILE",
        help="Pareto plot to write, PNG (default: --out with the suffix .png)",
    )  # fmt: skip
    parser.add_argument("--no-plot", action="store_true", help="write the table only")
    parser.add_argument(
        "--quick", action="store_true",
        help="smallest lattice of each scene only, no knob variants",
    )  # fmt: skip
    parser.add_argument(
        "--scene", action="append", metavar="NAME",
        help="measure this scene only (repeatable): rope, rope-plucked, membrane",
    )  # fmt: skip
    parser.add_argument(
        "--rounds", type=bounded_int(2, why='the first sweep warms up'), default=6, metavar="N",
        help="sweeps over the time grid per case, the first untimed (default 6)",
    )  # fmt: skip
    add_executor_arguments(parser)  # the cases' accuracy; the timings are serial whatever it is
    parser.set_defaults(handler=_run_tradeoff)


def _run_tradeoff(args: argparse.Namespace) -> int:
    from membrane_models.artifacts.zoo_index import list_models
    from membrane_server.tradeoff import (
        SCENE_PROBLEMS,
        Case,
        Measurement,
        measure_cases,
        plan_cases,
    )
    from membrane_server.tradeoff_report import markdown_report, plot_tradeoff

    if args.plot is None:
        args.plot = args.out.with_suffix(".png")
    plot_path = None if args.no_plot else args.plot
    if plot_path is not None:
        import matplotlib  # noqa: F401  (fail before measuring when the plot extra is missing)

    executor = executor_from_args(args)
    cases = plan_cases(args.scene or list(SCENE_PROBLEMS), quick=args.quick)

    def progress(done: int, total: int, case: Case, measurement: Measurement) -> None:
        what = f"{case.scene} {case.lattice_label} {case.model_label} {case.evaluator}"
        what += f" ({case.knobs})"
        if measurement.ok:
            outcome = (
                f"p50 {measurement.p50_us:.0f} us, p99 {measurement.p99_us:.0f} us, "
                f"error {measurement.relative_l2:.2e}"
            )
        else:
            outcome = f"not measured: {measurement.failure}"
        print(f"[{done}/{total}] {what}: {outcome}", file=sys.stderr, flush=True)

    parallel = None if executor.name == "serial" else executor
    measurements = measure_cases(cases, rounds=args.rounds, progress=progress, executor=parallel)
    text = markdown_report(
        measurements,
        _command_line(args),
        plot_path,
        args.out,
        rounds=args.rounds,
        zoo=list_models(),
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text + "\n")
    if plot_path is not None:
        plot_tradeoff(measurements, plot_path)
    measured = sum(m.ok for m in measurements)
    wrote = f"{args.out}" + (f" and {plot_path}" if plot_path is not None else "")
    print(f"membrane tradeoff: {measured}/{len(measurements)} cases measured; wrote {wrote}")
    return 0 if measured else 1


def _command_line(args: argparse.Namespace) -> str:
    """The command that regenerates these outputs, as written in the report."""
    words = ["membrane", "tradeoff", "--out", str(args.out)]
    words += ["--no-plot"] if args.no_plot else ["--plot", str(args.plot)]
    words += ["--quick"] if args.quick else []
    for scene in args.scene or []:
        words += ["--scene", scene]
    words += ["--rounds", str(args.rounds)]
    if args.executor == "ray" or args.ray_address is not None:  # the same figures, sooner
        words += ["--executor", "ray"]
    return shlex.join(words)
