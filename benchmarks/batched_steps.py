"""Figures for docs/LIVE.md (not a test): aggregate live steps per second of N sessions of
`membrane-live` on one server process, for N = 1, 8, 64 and 256, side by side in one run:

- ``single``: one client stepping its N sessions round-robin, one ``step`` request at a time
  (what the serving loop sees one by one: the unbatched baseline);
- ``steps``: the same client, one ``steps`` request per round of all N (``step_many``);
- ``columns``: the same client, one ``step_columns`` request per round of all N, its loads
  one array (``step_columns``; loads only);
- ``peers``: N peers (a DEALER socket each, one session each, in this one process) that each
  send their step and then read their reply, every round: the steps queue while the serving
  loop works, and it takes them together (``--max-batch``, default 256) ...
- ``peers unbatched``: ... against the same traffic on a second server with ``--max-batch 1``.

    .venv/bin/python benchmarks/batched_steps.py [--seconds 3] [--input load|probe]
        [--frame-every N] [--counts 1,8,64,256]
    .venv/bin/python benchmarks/batched_steps.py --kernel

``--kernel`` times the free step alone in this process (CPU time per session, 64 sessions of
`membrane-live`, one load each, side by side): numpy's expressions per session (the reference,
``FreeStepKernel(compiled=False)``), the same expressions over one (sessions x modes) array, and
the compiled pass per session, each with its modal force built.

Every step carries a force (``--input load``: a load held where it is; ``probe``: a probe in
contact, its force read back, which is stepped one session at a time); frames every 10th round.
The servers are `membrane serve` processes of their own (`--max-sessions 300`, one peer allowed
300), the clients this process: all on this machine's cores.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import zmq

from membrane_client import Client
from membrane_client.protocol import Request, decode
from membrane_client.session import Load, Probe, Session, step_columns, step_many

MEMBRANE = [sys.executable, "-m", "membrane_cli"]
COUNTS = (1, 8, 64, 256)


def _inputs(kind: str, index: int) -> dict[str, Any]:
    at = (0.2 + 0.6 * (index % 17) / 16, 0.5)
    if kind == "probe":
        return {"probes": [Probe(at, 0.002, 0.05)]}
    return {"loads": [Load(at, -0.5, 0.05)]}


def _client_rate(
    client: Client, sessions: list[Session], mode: str, seconds: float, kind: str, every: int = 10
) -> float:
    """Steps a second of one client stepping all its sessions every round: one ``step`` at a
    time (``single``), one ``steps`` request (``steps``) or one ``step_columns`` request of
    an array of loads (``columns``, loads only) a round."""
    steps, rounds = 0, 0
    started = time.perf_counter()
    deadline = started + seconds
    while time.perf_counter() < deadline:
        frame = rounds % every == every - 1
        if mode == "columns":
            rows = np.array([[*ld.at, ld.force, ld.radius] for i in range(len(sessions))
                             for ld in _inputs(kind, i)["loads"]])  # fmt: skip
            step_columns(client, sessions, rows, frames=frame)
        elif mode == "steps":
            items = [(s, {**_inputs(kind, i), "frame": frame}) for i, s in enumerate(sessions)]
            step_many(client, items)
        else:
            for i, session in enumerate(sessions):
                session.step(**_inputs(kind, i), frame=frame)
        steps += len(sessions)
        rounds += 1
    return steps / (time.perf_counter() - started)


def _peers_rate(address: str, count: int, seconds: float, kind: str, every: int = 10) -> float:
    """``count`` DEALER peers, each its own session, all stepping every round."""
    context: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    sockets = []
    for index in range(count):
        socket = context.socket(zmq.DEALER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.RCVTIMEO, 30_000)
        socket.connect(address)
        socket.send(Request("open", 0, session=f"peer-{count}-{index}").to_wire())
        assert decode(socket.recv())["ok"]
        sockets.append(socket)
    wire: list[dict[str, Any]] = [
        {k: [item.to_wire() for item in v] for k, v in _inputs(kind, i).items()}
        for i in range(count)
    ]
    steps, k = 0, 0
    started = time.perf_counter()
    try:
        while time.perf_counter() < started + seconds:
            frame = k % every == every - 1
            for index, socket in enumerate(sockets):
                request = Request("step", k, session=f"peer-{count}-{index}", k=k, frame=frame,
                                  token=f"t{index}", **wire[index])  # fmt: skip
                socket.send(request.to_wire())
            for socket in sockets:
                reply = decode(socket.recv())
                assert reply["ok"], reply
            steps += count
            k += 1
        return steps / (time.perf_counter() - started)
    finally:
        for index, socket in enumerate(sockets):
            socket.send(Request("close", k + 1, session=f"peer-{count}-{index}").to_wire())
            socket.recv()
            socket.close(linger=0)


@contextmanager
def _server(*extra: str) -> Iterator[str]:
    serve = subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", "membrane-live", "--bind", "tcp://127.0.0.1:*",
         "--max-sessions", "600", "--max-sessions-per-peer", "600", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert serve.stdout is not None
    address = ""
    for line in serve.stdout:
        found = re.search(r"listening on (\S+)", line)
        if found:
            address = found.group(1)
            break
    try:
        yield address
    finally:
        serve.terminate()
        serve.wait(30)


def _kernel_figures(rounds: int = 200, sessions: int = 64) -> dict[str, float]:
    """CPU microseconds per session of the free step three ways (module docstring)."""
    import numpy as np

    from membrane_models.live.free_step import FreeStepKernel, stacked_transition
    from membrane_server.heap import keep_temporaries_in_heap
    from membrane_server.served import ServedScene

    keep_temporaries_in_heap()  # as the server does: large temporaries stay in the heap
    engine = ServedScene.load("membrane-live").live
    assert engine is not None
    basis, box = engine.basis, engine.modes.box  # type: ignore[attr-defined]
    _, block = stacked_transition(engine.transition)  # type: ignore[attr-defined]
    loads = [_inputs("load", i)["loads"] for i in range(sessions)]
    prints = [basis.footprints(ld, (), engine.budget)[0] for ld in loads]  # type: ignore[attr-defined]
    factors = [[basis.modal_factors(fp) for fp in p] for p in prints]
    forces = [[ld[0].force] for ld in loads]
    rng = np.random.default_rng(0)
    q0 = [rng.standard_normal(box).reshape(-1) for _ in range(sessions)]
    v0 = [rng.standard_normal(box).reshape(-1) for _ in range(sessions)]
    for a in (*q0, *v0):
        a.flags.writeable = False
    numpy_rows = FreeStepKernel(block, "zoh", compiled=False)
    compiled = FreeStepKernel(block, "zoh")
    c = block

    def per_session(kernel: FreeStepKernel) -> None:
        for i in range(sessions):
            kernel.separable(q0[i], v0[i], q0[i], factors[i], forces[i])

    def wide() -> None:
        p1 = np.stack([f[0] * np.multiply.outer(*fs[0]).reshape(-1)
                       for f, fs in zip(forces, factors, strict=True)])  # fmt: skip
        q_all, v_all = np.stack(q0), np.stack(v0)
        q = c[0] * q_all
        q += c[1] * v_all
        q += c[4] * p1
        v = c[2] * q_all
        v += c[3] * v_all
        v += c[5] * p1
        [(q[i].copy(), v[i].copy()) for i in range(sessions)]

    figures = {}
    for name, run in (("numpy per session", lambda: per_session(numpy_rows)),
                      ("numpy over (sessions x modes)", wide),
                      ("compiled per session", lambda: per_session(compiled))):  # fmt: skip
        run()
        started = time.process_time()
        for _ in range(rounds):
            run()
        figures[name] = round((time.process_time() - started) / rounds / sessions * 1e6, 1)
    return figures


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--input", choices=["load", "probe"], default="load")
    parser.add_argument("--kernel", action="store_true", help="the free step alone, in process")
    parser.add_argument("--frame-every", type=int, default=10, help="frames every Nth round")
    parser.add_argument("--counts", default=",".join(map(str, COUNTS)), help="session counts")
    args = parser.parse_args()
    if args.kernel:
        print(json.dumps(_kernel_figures(), indent=2))
        return 0
    rows = []
    servers = (_server(), _server("--max-batch", "1"))
    with servers[0] as address, servers[1] as unbatched, Client(address, timeout=30.0) as client:
        for count in [int(n) for n in args.counts.split(",")]:
            sessions = [client.session("membrane-live") for _ in range(count)]
            every = args.frame_every
            single = _client_rate(client, sessions, "single", args.seconds, args.input, every)
            batch = _client_rate(client, sessions, "steps", args.seconds, args.input, every)
            columns = math.nan
            if args.input == "load":
                columns = _client_rate(client, sessions, "columns", args.seconds, args.input, every)
            for session in sessions:
                session.close()
            peers = _peers_rate(address, count, args.seconds, args.input, every)
            alone = _peers_rate(unbatched, count, args.seconds, args.input, every)
            rows.append({"sessions": count, "input": args.input, "frame_every": every,
                         "single_steps_per_s": round(single),
                         "steps_op_steps_per_s": round(batch),
                         "columns_steps_per_s": round(columns) if columns == columns else None,
                         "peers_steps_per_s": round(peers),
                         "peers_unbatched_steps_per_s": round(alone),
                         "steps_op_over_single": round(batch / single, 2),
                         "columns_over_single": round(columns / single, 2),
                         "peers_over_unbatched": round(peers / alone, 2),
                         "peers_over_single": round(peers / single, 2)})  # fmt: skip
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    print(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
