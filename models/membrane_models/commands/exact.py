"""The `membrane exact` command: evaluate an exact solution on a grid and save it as .npz.

This module imports with the core dependencies only (the dispatcher lists every command even on a
client-only install); the solver (scipy) and matplotlib are imported inside the handler.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from membrane_cli.arguments import UsageError
from membrane_models.problems import PARAMETER_HELP, PROBLEMS, make_problem

if TYPE_CHECKING:
    from membrane_models.problems import Problem

__all__ = ["add_exact", "parameters_help", "parse_assignments"]

logger = logging.getLogger(__name__)

DEFAULT_POINTS = {1: 101, 2: 41}  # per spatial axis
DEFAULT_TIMES = 101


def add_exact(subparsers: argparse._SubParsersAction) -> None:
    """Register ``membrane exact``."""
    parser = subparsers.add_parser(
        "exact",
        help="evaluate an exact reference solution on a grid and save it (.npz)",
        description=(
            "Evaluate the exact solution of a problem on a uniform grid of its space-time "
            "domain and write x, [y,] t and u (shaped (nx[, ny], nt)) plus the parameters to "
            "an .npz file. Problems: " + ", ".join(sorted(PROBLEMS)) + "."
        ),
        epilog=parameters_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,  # keeps the epilog's lines
    )
    parser.add_argument("problem", metavar="PROBLEM", help="problem name")
    parser.add_argument(
        "--set",
        dest="assignments",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        help="override a parameter (repeatable), e.g. --set C=8 --set x0=0.7",
    )
    parser.add_argument(
        "--nx", type=int, help="grid points along x (default 101 string, 41 membrane)"
    )
    parser.add_argument("--ny", type=int, help="grid points along y (membrane only; default 41)")
    parser.add_argument("--nt", type=int, default=DEFAULT_TIMES, help="time points (default 101)")
    parser.add_argument(
        "--rtol", type=float, default=1e-10, help="relative truncation error of series (1e-10)"
    )
    parser.add_argument("--out", required=True, type=Path, help="output file (.npz)")
    parser.add_argument("--plot", type=Path, help="also draw the solution to this image (.png)")
    parser.set_defaults(handler=_run_exact)


def parameters_help() -> str:
    """Every problem's parameters with their defaults, and what each one means: the names that
    --set (and a scene's [parameters] table) accept."""
    lines = ["parameters (--set NAME=VALUE, or a scene file's [parameters]), with defaults:"]
    for name in sorted(PROBLEMS):
        values = make_problem(name).parameters()
        lines.append(f"  {name}: " + ", ".join(f"{k}={v:g}" for k, v in values.items()))
    lines.append("meaning:")
    names = sorted({k for name in PROBLEMS for k in make_problem(name).parameters()})
    width = max(len(k) for k in names)
    lines += [f"  {k:<{width}}  {PARAMETER_HELP.get(k, '')}".rstrip() for k in names]
    return "\n".join(lines)


def parse_assignments(assignments: list[str]) -> dict[str, str]:
    """``["C=10", "x0=0.7"]`` -> ``{"C": "10", "x0": "0.7"}``; a missing ``=`` is an error."""
    parsed: dict[str, str] = {}
    for item in assignments:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise UsageError(f"--set expects NAME=VALUE, got {item!r}")
        parsed[name.strip()] = value.strip()
    return parsed


def _grid_sizes(args: argparse.Namespace, problem: Problem) -> tuple[int, ...]:
    """Points per axis (space first, then time), checked."""
    dims = problem.spatial_dims
    if args.ny is not None and dims == 1:
        raise UsageError(f"--ny is only for 2-D problems; {problem.name} is 1-D")
    nx = args.nx if args.nx is not None else DEFAULT_POINTS[dims]
    sizes = [("--nx", nx)]
    if dims == 2:
        sizes.append(("--ny", args.ny if args.ny is not None else DEFAULT_POINTS[dims]))
    sizes.append(("--nt", args.nt))
    for flag, n in sizes:
        if n < 2:
            raise UsageError(f"{flag} must be >= 2, got {n}")
    return tuple(n for _, n in sizes)


def _run_exact(args: argparse.Namespace) -> int:
    from membrane_models.exact import exact_solution  # scipy: the `server` extra

    if args.problem not in PROBLEMS:
        raise UsageError(f"unknown problem {args.problem!r}; known: {', '.join(sorted(PROBLEMS))}")
    problem = make_problem(args.problem, parse_assignments(args.assignments))
    sizes = _grid_sizes(args, problem)
    if args.out.suffix != ".npz":
        raise UsageError(f"--out must name an .npz file, got {str(args.out)!r}")
    if not args.rtol > 0.0:
        raise UsageError(f"--rtol must be > 0, got {args.rtol}")

    started = time.perf_counter()
    solution = exact_solution(problem, rtol=args.rtol)
    axes = [np.linspace(0.0, 1.0, n) for n in sizes[:-1]]
    t = np.linspace(0.0, problem.t_end, sizes[-1])
    u = solution.grid(*axes, t)
    elapsed = time.perf_counter() - started

    arrays = dict(zip(problem.axes, [*axes, t], strict=True))
    payload: dict[str, Any] = {
        **arrays,
        "u": u,
        "problem": np.array(args.problem),
        "parameters": np.array(json.dumps(problem.parameters(), sort_keys=True)),
        "n_modes": np.array(solution.n_modes),
        "truncation_error": np.array(solution.truncation_error),
    }
    with args.out.open("wb") as handle:
        np.savez(handle, **payload)
    if args.plot is not None:
        from membrane_models.commands.plotting import plot_solution  # matplotlib: the `plot` extra

        plot_solution(args.plot, args.problem, arrays, u)
    shape = "x".join(str(n) for n in u.shape)
    print(
        f"{args.problem}: u {shape}, max |u| = {np.abs(u).max():.4g}, "
        f"{solution.n_modes} modes, truncation error {solution.truncation_error:.2g}, "
        f"{elapsed:.2f} s -> {args.out}"
    )
    return 0
