"""Figures for docs/OPERATIONS.md (not a test): aggregate live steps per second with 1 and 2
workers (`membrane serve --workers N`), and one 1 kHz session's round trip beside them against
the echo's (`ping`), side by side in one run.

    .venv/bin/python benchmarks/workers_throughput.py [--clients 4] [--sessions 8] [--seconds 5]

Each of ``--clients`` processes holds ``--sessions`` sessions of `membrane-live` (a
``WorkerClient``: every session on the worker its id hashes to) and steps them round-robin as
fast as it can, frames every 10th step; meanwhile this process keeps one more session at 1 kHz
and times its round trips, then the same number of pings. The clients share the machine's cores
with the workers, as they would on one host.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "tests" / "helpers"))  # the tests' port finder
from serve_process import free_port_run

from membrane_client import Client
from membrane_client.workers import WorkerClient

MEMBRANE = [sys.executable, "-m", "membrane_cli"]


def _stepper(
    address: str, sessions: int, seconds: float, index: int, out: multiprocessing.Queue
) -> None:
    cluster = WorkerClient(address, timeout=5.0)
    opened = [
        cluster.session("membrane-live", session_id=f"c{index}-s{i}") for i in range(sessions)
    ]
    steps, deadline = 0, time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        for session in opened:
            session.step(frame=session.k % 10 == 9)
            steps += 1
    out.put(steps)
    cluster.close()


def _paced(address: str, seconds: float) -> dict[str, float]:
    """One session stepped every millisecond, and pings at the same pace: round trips (us)."""
    cluster = WorkerClient(address, timeout=5.0)
    session = cluster.session("membrane-live", session_id="paced")
    with Client(address, timeout=5.0) as echo:
        out = {}
        for name, call in (("step", lambda: session.step(frame=False)), ("ping", echo.ping)):
            times, next_at, end = [], time.perf_counter(), time.perf_counter() + seconds / 2
            while time.perf_counter() < end:
                started = time.perf_counter()
                call()
                times.append((time.perf_counter() - started) * 1e6)
                next_at += 1e-3
                time.sleep(max(0.0, next_at - time.perf_counter()))
            out[f"{name}_p50_us"] = float(np.percentile(times, 50))
            out[f"{name}_p99_us"] = float(np.percentile(times, 99))
    cluster.close()
    return out


def measure(workers: int, clients: int, sessions: int, seconds: float) -> dict[str, object]:
    base = free_port_run(workers)
    serve = subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", "membrane-live", "--workers", str(workers),
         "--bind", f"tcp://127.0.0.1:{base}", "--max-sessions", "1000",
         "--max-sessions-per-peer", "1000"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert serve.stdout is not None
    for line in serve.stdout:
        if re.search(r"listening on", line):
            break
    address = f"tcp://127.0.0.1:{base}"
    try:
        queue: multiprocessing.Queue = multiprocessing.Queue()
        procs = [
            multiprocessing.Process(target=_stepper, args=(address, sessions, seconds, i, queue))
            for i in range(clients)
        ]
        for p in procs:
            p.start()
        paced = _paced(address, seconds)
        total = sum(queue.get(timeout=60) for _ in procs)
        for p in procs:
            p.join(30)
    finally:
        serve.terminate()
        serve.wait(30)
    return {
        "workers": workers,
        "steps_per_s": round(total / seconds),
        **{k: round(v) for k, v in paced.items()},
    }


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--sessions", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    results = [measure(n, args.clients, args.sessions, args.seconds) for n in (1, 2)]
    print(json.dumps({"clients": args.clients, "sessions_per_client": args.sessions,
                      "results": results}, indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
