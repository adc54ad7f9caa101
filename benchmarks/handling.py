"""The server's own handling time per op, without ZeroMQ: ``Dispatcher.handle`` plus the stats.

Two ways, both on the built-in ``membrane`` scene (20 x 20, exact, frames on the grid):

- back to back (best of 7 rounds of 5,000, microseconds per request): the instruction cost;
- one request per millisecond (a simulator's pace; p50 and p99 of 3,000): the cost as a 1 kHz
  server pays it, the thread sleeping in between (as a server blocked in poll does), or with
  ``--busy`` busy-waiting in between (as `membrane serve --spin-us` does).

    python benchmarks/handling.py [--scene membrane] [--pace-ms 1] [--busy]
"""

from __future__ import annotations

import argparse
import sys
import time
import uuid

import numpy as np

from membrane_client.protocol import Request
from membrane_server.server import Server

OPS = ("query", "describe", "hello", "stats", "ping")


def _requests(op: str, steps: int) -> list[bytes]:
    session = uuid.uuid4().hex
    if op == "query":
        return [
            Request(op, k, t=(k % steps) * 0.01, session=session).to_wire() for k in range(1000)
        ]
    return [Request(op, k, session=session).to_wire() for k in range(1000)]


def _answer(server: Server, payload: bytes) -> None:
    answer = server.dispatcher.handle([payload])
    server.stats.record(1e-5, answer.op, answer.error, answer.scene, answer.session)


def back_to_back(server: Server, payloads: list[bytes], count: int = 5000) -> float:
    """Best of 7 rounds: microseconds per request."""
    best = float("inf")
    for _ in range(7):
        started = time.perf_counter()
        for k in range(count):
            _answer(server, payloads[k % len(payloads)])
        best = min(best, (time.perf_counter() - started) / count)
    return best * 1e6


def paced(
    server: Server, payloads: list[bytes], pace_s: float, busy: bool, count: int = 3000
) -> str:
    """p50 and p99 in microseconds with a pause of ``pace_s`` before each request."""
    samples = []
    for k in range(count):
        _pause(pace_s, busy)
        started = time.perf_counter_ns()
        _answer(server, payloads[k % len(payloads)])
        samples.append(time.perf_counter_ns() - started)
    micros = np.asarray(samples[count // 10 :]) / 1e3
    return f"p50 {np.percentile(micros, 50):.1f}, p99 {np.percentile(micros, 99):.1f}"


def _pause(seconds: float, busy: bool) -> None:
    if not busy:
        time.sleep(seconds)
        return
    until = time.perf_counter() + seconds
    while time.perf_counter() < until:
        pass


def main(argv: list[str] | None = None) -> int:
    """Print both figures per op."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane")
    parser.add_argument("--pace-ms", type=float, default=1.0)
    parser.add_argument("--busy", action="store_true", help="busy-wait between paced requests")
    args = parser.parse_args(argv)
    server = Server([args.scene], bind="tcp://127.0.0.1:*")  # never started: no socket
    steps = next(iter(server.dispatcher.scenes.values())).timeline.last_step + 1
    for op in OPS:
        payloads = _requests(op, steps)
        tight = back_to_back(server, payloads)
        slow = paced(server, payloads, args.pace_ms / 1e3, args.busy)
        wait = "busy-waiting" if args.busy else "sleeping"
        print(f"{op:9s} back to back {tight:6.1f} us; one per {args.pace_ms:g} ms, {wait} in "
              f"between: {slow} us")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
