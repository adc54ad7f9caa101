"""`membrane data koopman-string`: write the Kirchhoff string's datasets (.npz, split by shape).

This module imports with the core dependencies only; the solver (scipy) is imported inside the
handler. Progress goes to stderr: a bar redrawn in place on a terminal, one line per family and
split otherwise (a log file or a pipe gets no carriage returns).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TextIO

from membrane_cli.arguments import UsageError, bounded_float, bounded_int
from membrane_models.executors import RayExecutor, add_executor_arguments, executor_from_args
from membrane_models.problems.string_shapes import FAMILIES  # numpy only: a core dependency

__all__ = ["add_data"]


def add_data(subparsers: argparse._SubParsersAction) -> None:
    """Register `membrane data` and its datasets."""
    parser = subparsers.add_parser(
        "data",
        help="generate training data for data-driven networks",
        description="Generate datasets from the project's own reference solvers.",
    )
    datasets = parser.add_subparsers(title="datasets", dest="dataset", metavar="DATASET")
    datasets.required = True
    _add_koopman_string(datasets)


def _add_koopman_string(datasets: argparse._SubParsersAction) -> None:
    parser = datasets.add_parser(
        "koopman-string",
        help="the Kirchhoff-Carrier string: (u, u_t) snapshots, split by shape",
        description=(
            "Trajectories of the Kirchhoff-Carrier string u_tt = (c^2 + k int u_x^2) u_xx "
            "(c = 1, k = 100) from seeded initial shapes (smoothed square pulses, sines, "
            "band-limited white noise, kinked and smoothed plucks; half with an initial "
            "velocity), scaled to a nonlinearity k S*/c^2 drawn log-uniformly from linear to "
            "strong. Writes OUT/train.npz, OUT/validation.npz and OUT/test.npz: (u, u_t) on "
            "128 interior points every dt = 0.01, with the generator's parameters."
        ),
    )
    count = bounded_int(0, 100_000)
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--seed", type=bounded_int(0), default=0, help="seed (default 0)")
    for split, default in (("train", 12), ("validation", 3), ("test", 3)):
        parser.add_argument(
            f"--{split}",
            type=count,
            default=default,
            metavar="N",
            help=f"{split} trajectories per family (default {default})",
        )
    parser.add_argument(
        "--steps",
        type=bounded_int(1, 1_000_000),
        default=200,
        metavar="N",
        help="steps of dt = 0.01 per trajectory (default 200)",
    )
    parser.add_argument(
        "--families",
        default=",".join(FAMILIES),
        metavar="LIST",
        help="comma-separated subset of " + ", ".join(FAMILIES),
    )
    positive = bounded_float(0.0, exclusive=True)
    parser.add_argument(
        "--square-width", type=positive, default=0.02, help="square pulses' edge s.d. (0.02)"
    )
    parser.add_argument(
        "--pluck-smoothing", type=positive, default=0.02, help="smoothed plucks' s.d. (0.02)"
    )
    parser.add_argument(
        "--noise-modes", type=bounded_int(1, 128), default=16, help="noise band (16 modes)"
    )
    parser.add_argument(
        "--velocity-fraction", type=bounded_float(0.0), default=0.5, help="in [0, 1] (0.5)"
    )
    parser.add_argument(
        "--min-nonlinearity", type=positive, default=1e-3, help="smallest k S*/c^2 (1e-3)"
    )
    parser.add_argument(
        "--max-nonlinearity", type=positive, default=1.0, help="largest k S*/c^2 (1)"
    )
    parser.add_argument(
        "--jobs", type=bounded_int(1, 64), default=1, help="processes (default 1; same bytes)"
    )
    add_executor_arguments(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress on stderr")
    parser.set_defaults(handler=_run_koopman_string)


def _run_koopman_string(args: argparse.Namespace) -> int:
    from membrane_models.data.koopman import DatasetSpec, write_datasets
    from membrane_models.problems.string_shapes import ShapeParameters

    families = tuple(f.strip() for f in args.families.split(",") if f.strip())
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown or not families:
        raise UsageError(f"--families: unknown {unknown}; known: {', '.join(FAMILIES)}")
    if args.velocity_fraction > 1.0:
        raise UsageError(f"--velocity-fraction must lie in [0, 1], got {args.velocity_fraction}")
    if args.min_nonlinearity > args.max_nonlinearity:
        raise UsageError("--min-nonlinearity must not exceed --max-nonlinearity")
    if args.train + args.validation + args.test == 0:
        raise UsageError("nothing to generate: --train, --validation and --test are all 0")
    spec = DatasetSpec(
        seed=args.seed,
        counts=(args.train, args.validation, args.test),
        families=families,
        steps=args.steps,
        nonlinearity=(args.min_nonlinearity, args.max_nonlinearity),
        velocity_fraction=args.velocity_fraction,
        shapes=ShapeParameters(
            square_width=args.square_width,
            pluck_smoothing=args.pluck_smoothing,
            noise_modes=args.noise_modes,
        ),
    )
    where = executor_from_args(args)
    if isinstance(where, RayExecutor) and args.jobs > 1:
        raise UsageError("--jobs is a local process pool: give it or --executor ray, not both")
    started = time.perf_counter()
    progress = None if args.no_progress else _Progress(sys.stderr, started)
    try:
        if isinstance(where, RayExecutor):
            with where.futures() as tasks:
                paths = write_datasets(spec, args.out, progress, executor=tasks)
        else:
            paths = write_datasets(spec, args.out, progress, jobs=args.jobs)
    finally:
        if progress is not None:
            progress.close()
    elapsed = time.perf_counter() - started
    written = ", ".join(f"{p.name} ({spec.count(s) * len(families)})" for s, p in paths.items())
    print(f"koopman-string: wrote {written} to {args.out} in {elapsed:.1f} s")
    return 0


class _Progress:
    """Trajectories done: a bar on a terminal, a line per finished group elsewhere."""

    def __init__(self, stream: TextIO, started: float) -> None:
        self.stream = stream
        self.started = started
        self.tty = stream.isatty()
        self.label = ""
        self.drawn = False

    def __call__(self, done: int, total: int, label: str) -> None:
        elapsed = time.perf_counter() - self.started
        if self.tty:
            filled = round(30 * done / total)
            bar = "#" * filled + "-" * (30 - filled)
            self.stream.write(f"\r[{bar}] {done}/{total} {label:<20} {elapsed:6.1f} s")
            self.drawn = True
        else:
            if label != self.label and self.label:
                self._line(done - 1, total, elapsed)
            self.label = label
            if done == total:
                self._line(done, total, elapsed)
        self.stream.flush()

    def _line(self, done: int, total: int, elapsed: float) -> None:
        self.stream.write(f"koopman-string: {self.label} done ({done}/{total}, {elapsed:.1f} s)\n")

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
