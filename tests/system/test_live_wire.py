"""Live sessions over real ZeroMQ sockets: a proxy that loses every third reply cannot make a step
apply twice, and two clients stepping one session cannot both win."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import zmq
from attackers import WatchedServer

from membrane_client import Client, Load, Probe, ServerError, Session
from membrane_client.protocol import ErrorCode, decode, peek_reply
from membrane_server.server import Server

STEPS = 1000


def _inputs(k: int) -> dict[str, Any]:
    """Loads and probes that change with k: a step applied twice, or skipped, shows."""
    depth = 4e-4 * (1.0 + np.sin(k / 37.0))
    return {
        "loads": [Load((0.25, 0.7), 0.01 * np.cos(k / 11.0), 0.05)],
        "probes": [Probe((0.5, 0.5), depth, 0.05)],
        "frame": k % 100 == 99,
    }


@contextmanager
def lossy_proxy(server: str, drop: Callable[[int], bool]) -> Iterator[tuple[str, list[int]]]:
    """A relay on loopback that drops the replies ``drop`` picks (by count).

    Clients connect to its ROUTER; it sends each request on through one DEALER (the server
    answers one envelope level) and routes the reply back by its request id.
    """
    context: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    front = context.socket(zmq.ROUTER)
    front.setsockopt(zmq.LINGER, 0)
    front.bind("tcp://127.0.0.1:*")
    back = context.socket(zmq.DEALER)
    back.setsockopt(zmq.LINGER, 0)
    back.connect(server)
    stop = threading.Event()
    counts = [0, 0]  # replies relayed, replies dropped
    peers: dict[int, bytes] = {}  # request id -> the client connection that sent it

    def relay() -> None:
        poller = zmq.Poller()
        poller.register(front, zmq.POLLIN)
        poller.register(back, zmq.POLLIN)
        while not stop.is_set():
            ready = dict(poller.poll(50))
            if front in ready:
                peer, _, payload = front.recv_multipart()  # a REQ client: [peer, b"", request]
                peers[decode(payload)["id"]] = peer
                back.send_multipart([b"", payload])
            if back in ready:
                _, reply = back.recv_multipart()
                counts[0] += 1
                if drop(counts[0]):
                    counts[1] += 1
                    continue
                front.send_multipart([peers[peek_reply(reply)[0]], b"", reply])

    thread = threading.Thread(target=relay, daemon=True)
    thread.start()
    try:
        yield front.getsockopt_string(zmq.LAST_ENDPOINT), counts
    finally:
        stop.set()
        thread.join(5)
        front.close(0)
        back.close(0)


def _run(client: Client) -> np.ndarray:
    with client.session("membrane-live") as session:
        for k in range(STEPS):
            session.step(**_inputs(k))
        assert session.k == STEPS
        z = session.frame().z
        assert z is not None
        return z


@pytest.mark.slow
def test_a_lazy_pirate_session_through_a_lossy_proxy_applies_each_step_once(
    start_server: Callable[..., Server],
) -> None:
    server = start_server(["membrane-live"])
    with Client(server.address, timeout=2.0) as client:
        undisturbed = _run(client)
    with (
        lossy_proxy(server.address, lambda n: n % 3 == 0) as (address, counts),
        Client(address, timeout=0.03, retries=30) as client,
    ):
        disturbed = _run(client)
    assert counts[1] >= STEPS // 3  # every third reply lost, so about 333 re-sends
    np.testing.assert_array_equal(disturbed, undisturbed)
    # Each lost step reply came back as the stored one (a lost open, read or close is re-sent
    # too, but those are not steps).
    assert server.sessions.counts["resent"] >= counts[1] - 3
    assert server.sessions.counts["steps"] == 2 * STEPS


def test_two_clients_on_one_session_over_the_wire(start_server: Callable[..., Server]) -> None:
    server = start_server(["membrane-live"])
    with Client(server.address, timeout=2.0) as first, Client(server.address, timeout=2.0) as other:
        mine = first.session()
        theirs = Session(other, None, session_id=mine.id)  # joins, believing k = 0
        mine.step(probes=[Probe((0.5, 0.5), 1e-3, 0.05)])
        before = mine.frame().z
        with pytest.raises(ServerError) as refused:
            theirs.step(loads=[Load((0.5, 0.5), 1.0, 0.05)])
        assert refused.value.code == ErrorCode.STEP_MISMATCH
        assert "k = 1" in refused.value.message
        np.testing.assert_array_equal(mine.frame().z, before)  # the loser changed nothing
        theirs.k = 1
        assert theirs.step().k == 2  # told the count, it may go on
        mine.close()


# A stepper process: the reproduction's client A or B. For each session id read from stdin it
# joins the session (a new Session, request ids numbered from 1 like every Client's) and steps
# k = 0 with its own load, printing "ok" or the refusal's code, one line per id.
_STEPPER = """
import sys
from membrane_client import Client, Load, ServerError, Session
address, force = sys.argv[1], float(sys.argv[2])
with Client(address, timeout=10.0, retries=0) as client:
    print("ready", flush=True)
    for line in sys.stdin:
        session = Session(client, "membrane-live", session_id=line.strip())
        try:
            session.step(loads=[Load((0.5, 0.5), force, 0.05)], frame=False)
            print("ok", flush=True)
        except ServerError as refused:
            print(refused.code, flush=True)
"""
RACES, BATCH = 1000, 10


@pytest.mark.slow
def test_two_processes_stepping_one_session_never_both_win() -> None:
    """The reproduction of two clients on one session id (keyless: an id is a bearer token),
    1,000 times: A and B, two processes, each step k = 0 at once; exactly one gets ok."""
    server = WatchedServer(["membrane-live"])
    steppers = [_stepper(server.address, force) for force in (1e-2, -1e-2)]
    outcomes: dict[tuple[str, str], int] = {}
    try:
        for stepper in steppers:
            assert _line(stepper) == "ready"
        with Client(server.address, timeout=10.0) as owner:
            for _ in range(RACES // BATCH):
                sessions = [owner.session("membrane-live") for _ in range(BATCH)]
                ids = "".join(f"{session.id}\n" for session in sessions)
                for stepper in steppers:
                    _write(stepper, ids)
                for _ in sessions:
                    pair = (_line(steppers[0]), _line(steppers[1]))
                    outcomes[pair] = outcomes.get(pair, 0) + 1
                for session in sessions:
                    session.close()
    finally:
        for stepper in steppers:
            if stepper.stdin is not None:
                stepper.stdin.close()
            stepper.wait(timeout=30)
        server.close()
    print(f"\n{RACES} races of A and B on one session: {outcomes}")
    mismatch = ErrorCode.STEP_MISMATCH.value
    assert set(outcomes) <= {("ok", mismatch), (mismatch, "ok")}, outcomes
    assert sum(outcomes.values()) == RACES
    assert server.tracebacks() == []


def _stepper(address: str, force: float) -> subprocess.Popen[str]:
    command = [sys.executable, "-c", _STEPPER, address, str(force)]
    return subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _write(process: subprocess.Popen[str], text: str) -> None:
    assert process.stdin is not None
    process.stdin.write(text)
    process.stdin.flush()


def _line(process: subprocess.Popen[str]) -> str:
    assert process.stdout is not None
    return process.stdout.readline().strip()
