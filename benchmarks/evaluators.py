"""The latency goals, per evaluator: `membrane bench` against each way of serving a scene.

For every evaluator the scene can be served with (exact and a table of exact frames always;
separable, network and a table of the network when the zoo ships a model for the scene's
problem), a server process serves the scene that way and the load tester runs, each time with its
echo baseline measured in the same run:

- open loop at ``--rate`` (1 kHz) for ``--duration`` (10 s), queries cycling over the scene's
  time steps: p99 against the echo's p99 (goal: within 1.5x) and missed deadlines (goal: none);
- closed loop with ``--concurrency`` requests in flight: throughput against the echo's (goal:
  within 1.5x).

Prints a markdown table (the one in docs/BENCHMARKS.md) and, with --json, writes every figure.

    python benchmarks/evaluators.py [--scene membrane] [--rate 1000] [--duration 10] [--json F]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from membrane_bench.bench import BenchReport, probe, run_bench
from membrane_bench.loadtest import LoadSpec
from membrane_client.client import Client
from membrane_models.artifacts.zoo_index import list_models, resolve_model
from membrane_models.problems import make_problem
from membrane_server.scene import load_scene
from membrane_server.tradeoff import SCENE_PROBLEMS, Case, CaseServer

logger = logging.getLogger("benchmarks.evaluators")

GOAL_RATIO = 1.5


@dataclass(frozen=True)
class Row:
    """One evaluator's open- and closed-loop reports."""

    case: Case
    open_loop: BenchReport
    closed_loop: BenchReport
    server_side_us: dict[str, Any]


def cases_for(scene: str, model: str | None) -> list[Case]:
    """Exact and table-of-exact, plus separable/network/table of a shipped model if any."""
    problem = SCENE_PROBLEMS[scene]
    base = load_scene(scene)
    lattice = base.lattice.shape
    cases = [Case(scene, None, "exact", lattice), Case(scene, None, "table", lattice)]
    names = [model] if model else [m for m in list_models() if _problem_of(m) == problem]
    for name in names[:1]:
        manifest = resolve_model(name)
        kinds = ["network", *(["separable"] if manifest.separable else []), "table"]
        cases += [Case(scene, name, kind, lattice) for kind in kinds]
    return cases


def _problem_of(model: str) -> str:
    """The problem a zoo model solves (a registry variant counts as its problem)."""
    return make_problem(resolve_model(model).problem).name


def measure(case: Case, server: CaseServer, args: argparse.Namespace) -> Row | None:
    """Serve one case and run both loads against it (each with its echo baseline)."""
    try:
        address, build_s = server.serve(case)
    except ValueError as exc:
        logger.warning("%s %s: not served: %s", case.model_label, case.evaluator, exc)
        return None
    try:
        logger.info(
            "%s %s served on %s (built in %.2f s)",
            case.model_label,
            case.evaluator,
            address,
            build_s,
        )
        target = probe(address)
        open_spec = LoadSpec(mode="open", rate=args.rate, duration=args.duration, warmup=1.0)
        open_report = run_bench(target, open_spec, baseline=True, segments=args.segments)
        with Client(address, timeout=5.0) as client:  # the server's own time per request so far
            server_side = client.stats().latency_us or {}
        closed_spec = LoadSpec(
            mode="closed", concurrency=args.concurrency, duration=args.duration, warmup=1.0
        )
        closed_report = run_bench(target, closed_spec, baseline=True, segments=args.segments)
    finally:
        server.done()
    return Row(case, open_report, closed_report, server_side)


def markdown(rows: list[Row], args: argparse.Namespace) -> str:
    """The goals table."""
    lines = [
        f"| evaluator | model | {args.rate:g} Hz p50 / p99 / p99.9 us | echo p99 us "
        "| p99 vs echo | missed (echo) | server-side p50 / p99 us | closed loop req/s "
        "| echo req/s | req/s vs echo | goals met |",
        "| --- | --- | --- | ---: | ---: | --- | --- | ---: | ---: | ---: | :---: |",
    ]
    for row in rows:
        opened, closed = row.open_loop, row.closed_loop
        assert opened.baseline is not None and closed.baseline is not None
        ours, echo = opened.server.percentiles(), opened.baseline.percentiles()
        p99_ratio = (opened.vs_baseline() or {})["p99"]
        throughput_ratio = (closed.vs_baseline() or {})["throughput"]
        missed = opened.server.missed_deadlines or 0
        failed = sum(opened.server.errors.values()) + sum(closed.server.errors.values())
        met = p99_ratio <= GOAL_RATIO and missed == 0 and failed == 0
        met = met and throughput_ratio <= GOAL_RATIO
        kind = row.case.evaluator
        if kind == "table":
            kind += " of exact" if row.case.model is None else " of the model"
        side = row.server_side_us
        lines.append(
            f"| {kind} | {row.case.model_label} "
            f"| {ours['p50']:.0f} / {ours['p99']:.0f} / {ours['p99.9']:.0f} "
            f"| {echo['p99']:.0f} | {p99_ratio:.2f}x "
            f"| {missed} ({opened.baseline.missed_deadlines}) "
            f"| {side.get('p50', 0):.0f} / {side.get('p99', 0):.0f} "
            f"| {closed.server.throughput:.0f} | {closed.baseline.throughput:.0f} "
            f"| {throughput_ratio:.2f}x | {'yes' if met else 'no'} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; prints the markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane", choices=sorted(SCENE_PROBLEMS))
    parser.add_argument("--model", help="zoo model (default: the first shipped for the scene)")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--concurrency", type=int, default=2)
    parser.add_argument("--segments", type=int, default=5, help="server/echo alternations")
    parser.add_argument("--json", type=Path, help="write every figure here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", stream=sys.stderr)
    rows = []
    logger.info("load average before: %.2f", os.getloadavg()[0])
    with CaseServer() as server:
        for case in cases_for(args.scene, args.model):
            row = measure(case, server, args)
            if row is not None:
                rows.append(row)
    print(markdown(rows, args))
    print(f"\nload average (1 min) at the end: {os.getloadavg()[0]:.2f}")
    if args.json is not None:
        data: list[dict[str, Any]] = [
            {
                "evaluator": row.case.evaluator,
                "model": row.case.model_label,
                "open_loop": row.open_loop.to_dict(),
                "closed_loop": row.closed_loop.to_dict(),
            }
            for row in rows
        ]
        args.json.write_text(json.dumps(data, indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
