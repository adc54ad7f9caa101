"""`membrane bench`: load-test a server, optionally against the echo baseline.

This module imports with the core dependencies only; the load tester itself (HDR histograms,
progress bars) needs the ``bench`` extra and is imported when the command runs.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path
from typing import Any

from membrane_cli.arguments import UsageError, bounded_float, bounded_int
from membrane_cli.connection import add_connection_arguments

__all__ = ["add_bench"]

POSITIVE = bounded_float(0.0, exclusive=True)
NON_NEGATIVE = bounded_float(0.0)
FINITE = bounded_float()
COUNT = bounded_int(1)

logger = logging.getLogger(__name__)

DEFAULT_RATE_HZ = 1000.0


def add_bench(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane bench`."""
    parser = subparsers.add_parser(
        "bench",
        help="load-test a server: latency percentiles, throughput, errors",
        description=(
            "Load-test a membrane server. Open loop (--rate, the default: 1000 Hz): each request "
            "is due at a fixed time and its latency counts from then, so a stall shows in the "
            "percentiles (coordinated omission corrected, as wrk2). Closed loop (--concurrency): "
            "N requests in flight. Queries cycle through the scene's time steps. --baseline runs "
            "the same load against a bare ZeroMQ echo server and reports how many times slower "
            "the server is. Exit code 1 when any request failed or the rate could not be kept "
            "(requests still unsent at the end)."
        ),
    )
    add_connection_arguments(parser, timeout=1.0, curve=False)
    parser.add_argument(
        "--scene", metavar="NAME", help="scene to query (needed when the server hosts several)"
    )
    load = parser.add_mutually_exclusive_group()
    load.add_argument(
        "--rate",
        type=POSITIVE,
        metavar="HZ",
        help=f"open loop: total requests per second (default {DEFAULT_RATE_HZ:g})",
    )
    load.add_argument(
        "--concurrency",
        type=COUNT,
        metavar="N",
        help="closed loop: total requests in flight",
    )
    parser.add_argument(
        "--clients",
        type=COUNT,
        default=1,
        metavar="N",
        help="client processes; --rate and --concurrency are totals (default 1)",
    )
    parser.add_argument(
        "--duration",
        type=POSITIVE,
        default=10.0,
        metavar="S",
        help="measured seconds (default 10)",
    )
    parser.add_argument(
        "--warmup",
        type=NON_NEGATIVE,
        default=1.0,
        metavar="S",
        help="seconds of load before measuring (default 1)",
    )
    parser.add_argument(
        "--payload",
        choices=("query", "ping", "step", "step-frames"),
        default="query",
        help="what to send (default query); on a live scene, step (a probe pressing, forces "
        "only) or step-frames (with the frame), a session per client process",
    )
    parser.add_argument(
        "--t",
        type=FINITE,
        metavar="T",
        dest="fixed_t",
        help="query this time only, instead of cycling through the time steps",
    )
    parser.add_argument(
        "--deadline",
        type=POSITIVE,
        metavar="MS",
        help="open loop: a reply later than this is a missed deadline "
        "(default: one client period, 1000 * clients / rate ms)",
    )
    parser.add_argument(
        "--baseline",
        action="store_true",
        help="also run the same load against an echo server, report the ratios",
    )
    parser.add_argument(
        "--segments",
        type=COUNT,
        default=1,
        metavar="N",
        help="with --baseline: alternate server and echo N times, duration / N each, so that a "
        "changing background load weighs on both alike (default 1)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument(
        "--csv", type=Path, metavar="FILE", help="append one row per run to this CSV file"
    )
    parser.add_argument(
        "--quiet", action="store_true", help="no progress display (shown on a terminal only)"
    )
    parser.set_defaults(handler=_run_bench)


def _run_bench(args: argparse.Namespace) -> int:
    from membrane_bench.bench import BenchError, probe, run_bench
    from membrane_bench.loadtest import LoadSpec

    if args.fixed_t is not None and args.payload != "query":
        raise UsageError("--t applies to --payload query only")
    open_loop = args.concurrency is None
    spec = LoadSpec(
        mode="open" if open_loop else "closed",
        rate=(args.rate or DEFAULT_RATE_HZ) if open_loop else 0.0,
        concurrency=args.concurrency or 0,
        clients=args.clients,
        duration=args.duration,
        warmup=args.warmup,
        payload=args.payload,
        timeout=args.timeout,
        deadline=None if args.deadline is None else args.deadline / 1e3,
    )
    try:
        target = probe(args.connect, args.payload, args.scene, args.fixed_t, args.timeout * 2)
    except BenchError as exc:
        print(f"membrane bench: {exc}", file=sys.stderr)
        return 1
    # A bar redraws with carriage returns: on a pipe or in a log file that is one long line of
    # noise, so it shows only where a person watches a terminal.
    progress = None if args.quiet or not sys.stderr.isatty() else _progress_bars()
    report = run_bench(
        target, spec, baseline=args.baseline, progress=progress, segments=args.segments
    )
    if args.csv is not None:
        report.write_csv(args.csv)
    if args.json:
        print(json.dumps(_json_safe(report.to_dict()), indent=2))
    else:
        print(report.table())
    server = report.server
    failed = server.errors or server.unsent or server.ok < server.sent
    return 1 if failed else 0


def _progress_bars() -> Any:
    """A factory of progress hooks: one tqdm bar (on stderr) per run."""
    from tqdm import tqdm

    def make(label: str, spec: Any) -> Any:
        total = spec.warmup + spec.duration
        bar = tqdm(
            total=total,
            desc=label,
            unit="s",
            file=sys.stderr,
            leave=False,
            bar_format="{desc}: {bar} {n:.1f}/{total:.0f} s {postfix}",
        )

        def hook(elapsed: float, replies: int) -> None:
            bar.n = min(elapsed, total)
            bar.set_postfix_str(f"{replies} replies", refresh=False)
            bar.refresh()
            if elapsed >= total:
                bar.close()

        return hook

    return make


def _json_safe(value: Any) -> Any:
    """NaN (a percentile of nothing) becomes null: JSON has no NaN."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value
