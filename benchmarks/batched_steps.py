"""Figures for docs/LIVE.md (not a test): aggregate live steps per second of one client stepping
N sessions of `membrane-live` on one server, one `step` request per session against one `steps`
request per round of all N (side by side in one run), for N = 1, 8, 64 and 256.

    .venv/bin/python benchmarks/batched_steps.py [--seconds 3]

Every step carries a force (``--input load``: a load held where it is; ``probe``: a probe in
contact, its force read back); frames every 10th round. The
server is `membrane serve` in a process of its own (`--max-sessions 300`, one peer allowed 300),
the client this process: both on this machine's cores.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from typing import Any

from membrane_client import Client
from membrane_client.session import Load, Probe, Session, step_many

MEMBRANE = [sys.executable, "-m", "membrane_cli"]


def _inputs(kind: str, index: int) -> dict[str, Any]:
    at = (0.2 + 0.6 * (index % 17) / 16, 0.5)
    if kind == "probe":
        return {"probes": [Probe(at, 0.002, 0.05)]}
    return {"loads": [Load(at, -0.5, 0.05)]}


def _rate(
    client: Client, sessions: list[Session], batched: bool, seconds: float, kind: str
) -> float:
    steps, rounds = 0, 0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        frame = rounds % 10 == 9
        if batched:
            items = [(s, {**_inputs(kind, i), "frame": frame}) for i, s in enumerate(sessions)]
            step_many(client, items)
        else:
            for i, session in enumerate(sessions):
                session.step(**_inputs(kind, i), frame=frame)
        steps += len(sessions)
        rounds += 1
    return steps / seconds


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--input", choices=["load", "probe"], default="load")
    args = parser.parse_args()
    serve = subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", "membrane-live", "--bind", "tcp://127.0.0.1:*",
         "--max-sessions", "300", "--max-sessions-per-peer", "300"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert serve.stdout is not None
    address = ""
    for line in serve.stdout:
        found = re.search(r"listening on (\S+)", line)
        if found:
            address = found.group(1)
            break
    rows = []
    try:
        with Client(address, timeout=30.0) as client:
            for count in (1, 8, 64, 256):
                sessions = [client.session("membrane-live") for _ in range(count)]
                single = _rate(client, sessions, False, args.seconds, args.input)
                batch = _rate(client, sessions, True, args.seconds, args.input)
                rows.append({"sessions": count, "input": args.input,
                             "single_steps_per_s": round(single),
                             "batched_steps_per_s": round(batch),
                             "ratio": round(batch / single, 2)})  # fmt: skip
                for session in sessions:
                    session.close()
    finally:
        serve.terminate()
        serve.wait(30)
    print(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
