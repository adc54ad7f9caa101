"""What a query costs the server, against the bare ZeroMQ echo, over repeated alternating runs.

ROUNDS times: starts `membrane serve --scene SCENE [SERVE_ARGS]` in its own process; an open
loop at RATE Hz for DURATION s against the server and the echo in alternating segments
(`membrane bench --baseline --segments`); the server's own handling time for those requests
(its `stats`: receipt to reply handed to ZeroMQ); a closed loop (CONCURRENCY in flight) the same
way; stops the server. Prints each round and the median and range of each figure.

    python benchmarks/query_cost.py [--scene membrane] [--rounds 5] [--serve-arg=--spin-us=1000]
    python benchmarks/query_cost.py --scene membrane-live --payload step      # live, forces only
    python benchmarks/query_cost.py --scene benchmarks/scenes/membrane-live-100.toml \
        --payload step-frames --rate 100                                       # 100 x 100, frames

Run it with PYTHONPATH pointing at another checkout's client/, server/ and models/ to measure
that code the same way (the server subprocess inherits it).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from membrane_bench.bench import BenchReport, probe, run_bench
from membrane_bench.loadtest import PAYLOADS, LoadSpec
from membrane_client import Client

MEMBRANE = [sys.executable, "-m", "membrane_cli"]


def _start_server(scene: str, serve_args: Sequence[str]) -> tuple[subprocess.Popen[str], str]:
    command = [*MEMBRANE, "serve", "--scene", scene, "--bind", "tcp://127.0.0.1:*", *serve_args]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    line = process.stdout.readline()
    if "listening on " not in line:
        process.kill()
        raise SystemExit(f"the server did not start: {line!r}")
    return process, line.split("listening on ", 1)[1].split()[0]


def _handling(address: str) -> dict[str, Any]:
    with Client(address, timeout=5.0) as client:
        return dict(client.stats().latency_us or {})


def _round(args: argparse.Namespace) -> dict[str, float]:
    """One round on a server of its own, so that its handling figures are this round's."""
    process, address = _start_server(args.scene, args.serve_args)
    try:
        return _measure(address, args)
    finally:
        process.terminate()
        process.wait(10)


def _measure(address: str, args: argparse.Namespace) -> dict[str, float]:
    target = probe(address, args.payload)
    open_loop = run_bench(
        target,
        LoadSpec(
            mode="open", rate=args.rate, duration=args.duration, warmup=1.0, payload=args.payload
        ),
        baseline=True,
        segments=args.segments,
    )
    time.sleep(1.1)  # the server recomputes its percentiles at most once a second
    handling = _handling(address)
    closed = run_bench(
        target,
        LoadSpec(
            mode="closed",
            concurrency=args.concurrency,
            duration=args.duration / 2,
            payload=args.payload,
        ),
        baseline=True,
        segments=args.segments,
    )
    return {
        **_open_figures(open_loop),
        "handling p50": handling["p50"],
        "handling p99": handling["p99"],
        "closed server Hz": closed.server.throughput,
        "closed echo Hz": closed.baseline.throughput if closed.baseline else float("nan"),
    }


def _open_figures(report: BenchReport) -> dict[str, float]:
    server, echo = report.server.percentiles(), report.baseline.percentiles()  # type: ignore[union-attr]
    return {
        "server p50": server["p50"],
        "server p99": server["p99"],
        "echo p50": echo["p50"],
        "echo p99": echo["p99"],
        "p99 ratio": server["p99"] / echo["p99"],
        "server missed": float(report.server.missed_deadlines or 0),
        "echo missed": float(report.baseline.missed_deadlines or 0),  # type: ignore[union-attr]
    }


def main(argv: list[str] | None = None) -> int:
    """Run the rounds and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane")
    parser.add_argument("--payload", default="query", choices=PAYLOADS)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--segments", type=int, default=5)
    parser.add_argument("--concurrency", type=int, default=2)
    parser.add_argument("--serve-arg", action="append", default=[], dest="serve_args")
    args = parser.parse_args(argv)
    rounds: list[dict[str, float]] = []
    for index in range(args.rounds):
        figures = _round(args)
        rounds.append(figures)
        print(f"round {index + 1}: " + ", ".join(f"{k} {v:.1f}" for k, v in figures.items()),
              flush=True)  # fmt: skip
    print(
        f"\nmedian [min, max] of {args.rounds} rounds ({args.scene}, {args.payload}, "
        f"{' '.join(args.serve_args)}):"
    )
    for key in rounds[0]:
        values = [figures[key] for figures in rounds]
        print(f"  {key}: {statistics.median(values):.1f} [{min(values):.1f}, {max(values):.1f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
