"""Requests queued together are answered together (``Dispatcher.handle_many``, the serving loop's
``_receive_queued``): runs of steps of loads alone are stepped as one operation per engine, and
every reply is the one the request gets alone, byte for byte, in the same order of effects."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest
import zmq
from hypothesis import given, settings
from hypothesis import strategies as st

from membrane_client.protocol import Request, decode
from membrane_client.session import Load, Probe
from membrane_server.dispatch import Dispatcher
from membrane_server.served import ServedScene
from membrane_server.server import Server
from membrane_server.sessions import SessionTable

SESSIONS = 64


@pytest.fixture(scope="module")
def served() -> ServedScene:
    return ServedScene.load("membrane-live")


def _dispatcher(served: ServedScene, sessions: int = SESSIONS) -> Dispatcher:
    dispatcher = Dispatcher([served], sessions=SessionTable(300, 60.0, max_per_peer=300))
    for index in range(sessions):
        body = Request("open", index, session=f"s{index}").to_wire()
        opened = decode(dispatcher.handle([body]).reply)
        assert opened["ok"], opened
    return dispatcher


def _step(request_id: int, session: int, k: int, **options: Any) -> bytes:
    at = (0.1 + 0.012 * session, 0.2 + 0.009 * session)
    loads = options.pop("loads", [Load(at, -0.3 * (1 + k % 3), 0.05).to_wire()])
    fields = {"frame": k % 2 == 1, "token": f"t{session}", **options}
    return Request("step", request_id, session=f"s{session}", k=k, loads=loads, **fields).to_wire()


def _widths(dispatcher: Dispatcher) -> list[int]:
    """Spy on the engine's batched steps: the width of each call."""
    engine = dispatcher.scenes["membrane-live"].live
    assert engine is not None
    widths: list[int] = []
    real = engine.step_loads  # type: ignore[attr-defined]

    def spy(states: Any, loads: Any, frames: Any) -> Any:
        widths.append(len(states))
        return real(states, loads, frames)

    engine.step_loads = spy  # type: ignore[attr-defined]
    return widths


def test_a_run_of_64_sessions_steps_is_one_operation_and_the_lone_replies(
    served: ServedScene,
) -> None:
    alone, together = _dispatcher(served), _dispatcher(served)
    for k in range(4):
        bodies = [_step(1000 * k + i, i, k) for i in range(SESSIONS)]
        expected = [alone.handle([body]).reply for body in bodies]
        widths = _widths(together)
        answers = list(together.handle_many([([body], "") for body in bodies]))
        assert widths == [SESSIONS]
        assert [a.reply for a in answers] == expected
        assert all(a.op == "step" and a.error is None for a in answers)
    moved = decode(expected[1])["z"]
    assert np.abs(np.frombuffer(moved["data"], moved["dtype"])).max() > 1e-4


def test_a_run_keeps_the_order_of_effects(served: ServedScene) -> None:
    """A session's second step, a read, a probe, refusals and a re-send in one queue: each
    answered as alone, in order (the run ends where a step needs the one before it)."""
    alone, together = _dispatcher(served), _dispatcher(served)
    bodies = [
        _step(1, 0, 0),
        _step(2, 1, 0),
        _step(3, 0, 1),  # s0 again: needs step 1's end
        Request("read", 4, session="s0").to_wire(),
        _step(5, 2, 0, loads=[], probes=[Probe((0.5, 0.5), 0.002, 0.05).to_wire()]),
        _step(6, 3, 0, loads=[Load((0.5, 0.5), float("nan"), 0.05).to_wire()]),  # refused
        _step(7, 4, 5),  # the wrong k
        _step(8, 1, 0),  # a re-send of request 2
        _step(9, 5, 0),
        b"\x93not a request",
        _step(10, 6, 0),
    ]
    expected = [alone.handle([body]).reply for body in bodies]
    widths = _widths(together)
    answers = list(together.handle_many([([body], "") for body in bodies]))
    assert [a.reply for a in answers] == expected
    # s0 and s1; s0 again (the read ends the run); s5 (s2 probes: alone; s3 and s4 refused, s1
    # re-sent: none reaches the engine); s6, a run of one, is a lone step
    assert widths == [2, 1, 1]
    codes = [decode(a.reply).get("error", {}).get("code") for a in answers]
    assert codes[5] == "bad_request" and codes[6] == "step_mismatch" and codes[9] is not None
    assert decode(answers[3].reply)["k"] == 2  # the read saw both of s0's steps


@pytest.fixture
def server(many_sessions_server: Server) -> Server:
    return many_sessions_server


def _dealer(address: str) -> zmq.Socket[bytes]:
    socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.DEALER)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, 10_000)
    socket.connect(address)
    return socket


def test_steps_queued_from_many_peers_are_stepped_together(server: Server) -> None:
    """64 peers' steps queue while the loop is busy; it then answers them as one run, each
    peer its own reply, equal to a twin's lone steps."""
    sockets = [_dealer(server.address) for _ in range(SESSIONS)]
    try:
        for index, socket in enumerate(sockets):
            socket.send(Request("open", index, session=f"s{index}").to_wire())
            assert decode(socket.recv())["ok"]
        widths = _widths(server.dispatcher)
        release = threading.Event()
        ping = Dispatcher._ping

        def busy(self: Dispatcher, request: Request) -> dict[str, Any]:
            release.wait(10.0)  # the loop is held here while the steps queue
            return ping(self, request)

        Dispatcher._ping = busy  # type: ignore[method-assign]
        try:
            holder = _dealer(server.address)
            holder.send(Request("ping", 1).to_wire())
            time.sleep(0.2)
            bodies = [_step(100 + i, i, 0, frame=True) for i in range(SESSIONS)]
            for socket, body in zip(sockets, bodies, strict=True):
                socket.send(body)
            time.sleep(0.5)  # every step has reached the server's queue
            release.set()
            assert decode(holder.recv())["pong"]
            holder.close(linger=0)
        finally:
            Dispatcher._ping = ping  # type: ignore[method-assign]
        replies = [socket.recv() for socket in sockets]
    finally:
        for socket in sockets:
            socket.close(linger=0)
    assert max(widths) > 1, widths  # stepped together, not one by one
    twin = _dispatcher(ServedScene.load("membrane-live"))
    assert replies == [twin.handle([body]).reply for body in bodies]


_ACTIONS = st.lists(
    st.tuples(
        st.sampled_from(["step", "step", "step", "probe", "wrong k", "re-send", "read", "junk"]),
        st.integers(0, 5),
    ),
    min_size=1,
    max_size=24,
)


@settings(max_examples=25, deadline=None)
@given(actions=_ACTIONS)
def test_any_queue_is_answered_as_one_by_one(served: ServedScene, actions: list[Any]) -> None:
    """Property: whatever a queue holds (steps of six sessions, a session's next step, probes,
    wrong k, re-sends, reads, junk), ``handle_many`` gives ``handle``'s replies in order."""
    alone, together = _dispatcher(served, 6), _dispatcher(served, 6)
    taken = [0] * 6
    bodies = []
    for request_id, (action, session) in enumerate(actions):
        k = taken[session]
        if action == "step":
            bodies.append(_step(request_id, session, k))
            taken[session] += 1
        elif action == "probe":
            probe = [Probe((0.5, 0.5), 0.001, 0.05).to_wire()]
            bodies.append(_step(request_id, session, k, loads=[], probes=probe))
            taken[session] += 1
        elif action == "wrong k":
            bodies.append(_step(request_id, session, k + 3))
        elif action == "re-send" and k > 0:
            bodies.append(_step(request_id, session, k - 1))  # answered from the store
        elif action == "read":
            bodies.append(Request("read", request_id, session=f"s{session}").to_wire())
        else:
            bodies.append(b"\xc1")
    expected = [alone.handle([body]).reply for body in bodies]
    assert [a.reply for a in together.handle_many([([b], "") for b in bodies])] == expected
