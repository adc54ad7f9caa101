"""Where a query's time goes inside the server: the figures behind docs/BENCHMARKS.md's analysis.

1. ``Dispatcher.handle`` (decode, validate, frame, pack float32, encode) in a tight loop;
2. the same call timed inside a live server answering an open loop at ``--rate`` (1 kHz), next
   to the server's own receive-to-send time (its ``stats``);
3. one evaluator frame in a loop, per evaluator the zoo allows, on ``--lattice`` (e.g. 100 100):
   run it once as is and once with ``OPENBLAS_NUM_THREADS=1`` to see BLAS threading's share.

    python benchmarks/server_cost.py [--scene membrane] [--lattice 20 20] [--rate 1000]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np

from membrane_bench.bench import probe, run_bench
from membrane_bench.loadtest import LoadSpec
from membrane_client.protocol import Request
from membrane_server.dispatch import Answer, Dispatcher
from membrane_server.server import Server
from membrane_server.tradeoff import Case, build_case, plan_cases


def _percentiles_us(samples_ns: list[int]) -> str:
    values = np.asarray(samples_ns) / 1e3
    return f"p50 {np.percentile(values, 50):.1f} us, p99 {np.percentile(values, 99):.1f} us"


def _time_calls(call: Callable[[int], object], count: int, warmup: int = 200) -> list[int]:
    for k in range(warmup):
        call(k)
    samples = []
    for k in range(count):
        started = time.perf_counter_ns()
        call(k)
        samples.append(time.perf_counter_ns() - started)
    return samples


def tight_loop(case: Case, steps: int) -> str:
    """``Dispatcher.handle`` on query messages, back to back."""
    dispatcher = Dispatcher([build_case(case)], dict)
    messages = [Request("query", k, t=(k % steps) * 0.01).to_wire() for k in range(3000)]
    return _percentiles_us(_time_calls(lambda k: dispatcher.handle([messages[k]]), 3000))


def live_server(case: Case, rate: float) -> str:
    """``Dispatcher.handle`` timed inside a server under an open loop at ``rate``."""
    server = Server([build_case(case)], bind="tcp://127.0.0.1:*")
    inner = server.dispatcher.handle
    samples: list[int] = []

    def timed(body: Sequence[bytes], peer: str = "") -> Answer:
        started = time.perf_counter_ns()
        answer = inner(body, peer)
        samples.append(time.perf_counter_ns() - started)
        return answer

    server.dispatcher.handle = timed  # type: ignore[method-assign]
    address = server.start()
    try:
        run_bench(probe(address), LoadSpec(mode="open", rate=rate, duration=4.0, warmup=1.0))
        side = server.stats.latency_us()
    finally:
        server.stop()
    return (
        f"handle {_percentiles_us(samples)}; receive-to-send p50 {side['p50']:.1f} us, "
        f"p99 {side['p99']:.1f} us"
    )


def frame_cost(case: Case) -> str:
    """One evaluator frame, back to back."""
    evaluator = build_case(case).evaluator
    return _percentiles_us(_time_calls(lambda k: evaluator.frame((k % 101) * 0.01), 300, 50))


def main(argv: list[str] | None = None) -> int:
    """Print the three measurements."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane")
    parser.add_argument("--lattice", type=int, nargs="+", default=[20, 20])
    parser.add_argument("--rate", type=float, default=1000.0)
    args = parser.parse_args(argv)
    lattice = tuple(args.lattice)
    print(
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    reference = Case(args.scene, None, "exact", lattice)
    steps = 101
    print(f"1. Dispatcher.handle, tight loop, exact {lattice}: {tight_loop(reference, steps)}")
    print(
        f"2. live server at {args.rate:g} Hz, exact {lattice}: {live_server(reference, args.rate)}"
    )
    kinds = {(c.model, c.evaluator) for c in plan_cases([args.scene], quick=True)}
    for model, kind in sorted(kinds, key=lambda k: (k[0] or "", k[1])):
        case = Case(args.scene, model, kind, lattice)
        print(f"3. frame, {case.model_label} {kind} {lattice}: {frame_cost(case)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
