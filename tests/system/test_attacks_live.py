"""Attacks on the live surface through a real `membrane serve`: inputs the protocol allows that
used to stall, bloat, lock out or poison the server (docs/ROBUSTNESS.md, "Attacks", rows L1 to
L8).

One server per test, in its own process (RSS sampled, a watchdog at 1.5 GiB), hosting the two
built-in live scenes. A good client steps its own `membrane-live` session at 200 Hz the whole
time (``live_good_client``): first undisturbed, then during the attack, and the test asserts
it never failed nor waited 100 ms (its missed 5 ms deadlines are printed, and judged by
benchmarks/attack_deadlines.py); then that the server is
alive, its RSS within the stated bound, its log without a traceback, and every refusal a
structured error of at most 300 characters. Loopback only; every loop is bounded in count and
time.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq
from attackers import MiB, WatchedServer, dealer
from live_good_client import LiveGoodClient, check_against_undisturbed

from membrane_cli.keys_command import create_keypair
from membrane_client import Client, ServerError
from membrane_client.curve import SocketOptions, client_socket_options
from membrane_client.protocol import MAX_ERROR_CHARS, MAX_LOADS, decode, encode
from membrane_client.session import Session

pytestmark = pytest.mark.slow

SCENES = ["membrane-live", "rope-live"]
UNDISTURBED_S = 1.0
REPLY_TIMEOUT_MS = 5000
MEMBRANE_MIN_RADIUS = 0.00390625  # describe's live.min_radius on membrane-live
ROPE_MIN_RADIUS = 1.52587890625e-05  # and on rope-live


@pytest.fixture
def server() -> Iterator[WatchedServer]:
    watched = WatchedServer(SCENES)
    yield watched
    watched.close()


@pytest.fixture
def good(server: WatchedServer) -> Iterator[LiveGoodClient]:
    client = LiveGoodClient(server.address).start()
    yield client
    client.stop()


class Raw:
    """A raw DEALER peer: its own connection, numbered requests, every reply read."""

    def __init__(self, address: str, **options: Any) -> None:
        self.socket = dealer(address, REPLY_TIMEOUT_MS)
        for option, value in options.items():
            self.socket.setsockopt(getattr(zmq, option), value)
        self.next_id = 0

    def send(self, **message: Any) -> dict[str, Any]:
        self.next_id += 1
        self.socket.send_multipart([b"", encode({"v": 1, "id": self.next_id, **message})])
        return decode(self.socket.recv_multipart()[-1])

    def close(self) -> None:
        self.socket.close(linger=0)


def _refused(reply: dict[str, Any], code: str = "bad_request") -> str:
    assert reply["ok"] is False, reply
    error = reply["error"]
    assert error["code"] == code, error
    assert len(error["message"]) <= MAX_ERROR_CHARS, len(error["message"])
    return str(error["message"])


def _survived(server: WatchedServer, bound_mib: float, attack: str) -> None:
    growth = server.growth() / MiB
    print(f"\n{attack}: RSS +{growth:.1f} MiB (bound {bound_mib:g})")
    assert not server.killed_for_memory and server.alive, server.log[-20:]
    assert growth < bound_mib, f"{attack}: RSS grew {growth:.1f} MiB"
    assert server.tracebacks() == [], server.log[-40:]


def _undisturbed(good: LiveGoodClient, server: WatchedServer) -> Any:
    undisturbed = good.measure(UNDISTURBED_S)
    server.reset_peak()
    return undisturbed


def _loads(count: int, radius: float, dims: int = 2) -> list[dict[str, Any]]:
    return [
        {"at": [0.2 + 0.6 * i / MAX_LOADS] * dims, "force": 1.0, "radius": radius}
        for i in range(count)
    ]


# -- L1: CPU amplification through legal tiny-radius loads -------------------------------------


def test_tiny_footprints_are_priced_and_refused_before_they_cost(
    server: WatchedServer, good: LiveGoodClient, request: pytest.FixtureRequest
) -> None:
    """64 loads at min_radius made every later frame of the session cost 0.35-1.0 s (a good
    client at 200 Hz managed 20 steps in 20 s); a radius of 1e9 on rope-live 70 ms a step. Now
    such steps are refused by the cost model with its figure, and an attacker stepping the
    costliest steps the budget admits, back to back, leaves the good client on time."""
    undisturbed = _undisturbed(good, server)
    good.begin("attacked")
    attacker = Raw(server.address)
    try:
        assert attacker.send(op="open", scene="membrane-live", session="cpu")["ok"]
        message = _refused(attacker.send(
            op="step", scene="membrane-live", session="cpu", k=0,
            loads=_loads(MAX_LOADS, MEMBRANE_MIN_RADIUS),
        ))  # fmt: skip
        assert "ms of work, over the 5 ms" in message
        assert attacker.send(op="open", scene="rope-live", session="wide")["ok"]
        huge = [{"at": [0.5], "force": 1.0, "radius": 1e9}]
        assert "at most 10" in _refused(
            attacker.send(op="step", scene="rope-live", session="wide", k=0, loads=huge)
        )
        costly = _loads(1, 2 * MEMBRANE_MIN_RADIUS)  # within the budget, near its edge
        deadline, k, reads = time.monotonic() + 2.0, 0, 0
        while time.monotonic() < deadline:
            reply = attacker.send(
                op="step", scene="membrane-live", session="cpu", k=k, loads=costly, frame=False
            )
            assert reply["ok"], reply
            k += 1
            reads += attacker.send(op="read", scene="membrane-live", session="cpu")["ok"]
    finally:
        attacker.close()
    during = good.begin("after")
    check_against_undisturbed(request, f"L1 ({k} costly steps and reads)", undisturbed, during)
    _survived(server, 32, "L1")


# -- L2: session memory on rope-live ------------------------------------------------------------


def test_sessions_hold_at_most_what_describe_says(
    server: WatchedServer, good: LiveGoodClient, request: pytest.FixtureRequest
) -> None:
    """64 loads at rope-live's min_radius held about 124 MiB per session (RSS 111 to 2,601 MiB
    after 18 sessions) and left about 275 MiB in caches. Now: refused; 48 sessions (three
    connections, 16 each) stepped with the most spectra the budget lets a state hold stay
    within 48 session_bytes plus the engine's shared caches."""
    undisturbed = _undisturbed(good, server)
    good.begin("attacked")
    with Client(server.address, timeout=5.0) as probe:
        live = probe.describe("rope-live").live
    peers = [Raw(server.address) for _ in range(3)]
    opened = 0
    try:
        first = peers[0]
        assert first.send(op="open", scene="rope-live", session="m-0")["ok"]
        assert "ms of work" in _refused(first.send(
            op="step", scene="rope-live", session="m-0", k=0,
            loads=_loads(MAX_LOADS, ROPE_MIN_RADIUS, 1),
        ))  # fmt: skip
        for index in range(48):
            peer, session = peers[index // 16], f"m-{index}"
            # 65,536 spectrum entries (512 KiB) held, each at its own place: no shared cache
            held = [{"at": [0.2 + 0.01 * index], "force": 1.0, "radius": 4 * ROPE_MIN_RADIUS}]
            if index:
                assert peer.send(op="open", scene="rope-live", session=session)["ok"]
            assert peer.send(op="step", scene="rope-live", session=session, k=0, loads=held)["ok"]
            opened += 1
        time.sleep(1.0)  # held while the good client steps and the RSS sampler looks
    finally:
        for peer in peers:
            peer.close()
    during = good.begin("after")
    check_against_undisturbed(request, f"L2 ({opened} heavy sessions)", undisturbed, during)
    bound = (opened * live["session_bytes"] + live["engine_bytes"]) / MiB
    _survived(server, bound, f"L2 (bound: {opened} x session_bytes + engine_bytes)")


# -- L3: one peer takes every session -----------------------------------------------------------


def test_one_connection_cannot_take_every_session(
    server: WatchedServer, good: LiveGoodClient, request: pytest.FixtureRequest
) -> None:
    """One DEALER opened all 64 sessions and kept them alive with a read every few minutes:
    every other user got too_many_sessions. Now a peer holds at most 16."""
    undisturbed = _undisturbed(good, server)
    good.begin("attacked")
    greedy = Raw(server.address)
    try:
        replies = [greedy.send(op="open", scene="rope-live", session=f"g-{i}") for i in range(64)]
        held = sum(reply["ok"] for reply in replies)
        assert held == 16
        assert "this peer holds 16" in _refused(replies[-1], "too_many_sessions")
        deadline, reads = time.monotonic() + 1.0, 0
        while time.monotonic() < deadline:  # keeping them alive, and asking for more
            reads += greedy.send(op="read", scene="rope-live", session=f"g-{reads % 16}")["ok"]
            more = greedy.send(op="open", scene="rope-live", session="g-more")
            _refused(more, "too_many_sessions")
        with Client(server.address, timeout=5.0) as other, other.session("rope-live") as mine:
            assert mine.step().k == 1  # another user still opens and steps
    finally:
        greedy.close()
    during = good.begin("after")
    check_against_undisturbed(request, "L3 (64 opens from one connection)", undisturbed, during)
    _survived(server, 32, "L3")


# -- L4, L5, L6: bad values answered as structured errors, never internal_error ----------------


@dataclass(frozen=True)
class Bad:
    what: str
    message: dict[str, Any]


def _array(dtype: Any, shape: list[int], data: bytes) -> dict[str, Any]:
    return {"dtype": dtype, "shape": shape, "data": data}


def _bad_values() -> list[Bad]:
    def step(**fields: Any) -> dict[str, Any]:
        return {"op": "step", "scene": "membrane-live", "session": "bad", "k": 0, **fields}

    def open_with(array: dict[str, Any]) -> dict[str, Any]:
        initial = {"displacement": array}
        return {"op": "open", "scene": "membrane-live", "session": "bad-open", "initial": initial}

    probe = {"at": [0.5, 0.5], "radius": 0.05}
    load = {"at": [0.5, 0.5], "radius": 0.05}
    return [
        Bad("radius 1e-320", step(loads=[{**load, "force": 1.0, "radius": 1e-320}])),
        Bad("depth 1e308", step(probes=[{**probe, "depth": 1e308}])),
        Bad("force 2^63", step(loads=[{**load, "force": 2**63}])),
        Bad("65 axes", open_with(_array("<f4", [1] * 65, b"\0" * 4))),
        Bad("4,400-digit shape", open_with(_array("<f4", [2**63 - 1] * 230, b""))),
        Bad("100,000-char dtype", open_with(_array("y" * 100_000, [400], b"\0" * 1600))),
        Bad("initial 1e308", open_with(_array("<f8", [400], np.full(400, 1e308).tobytes()))),
        Bad("initial 3e38", open_with(_array("<f4", [400], np.full(400, 3e38, "<f4").tobytes()))),
    ]


def test_bad_values_are_bounded_refusals_that_log_nothing_and_poison_nothing(
    server: WatchedServer, good: LiveGoodClient, request: pytest.FixtureRequest
) -> None:
    """Before: internal_error and a 1.3 KB traceback per request for a subnormal radius, an
    initial array of 65 axes or a 4,300-digit shape product (1.76 MB/s of log from one
    client); a 100,071-character message for a long dtype; ok: true with inf or NaN frames for
    a depth of 1e308 or an initial shape of 1e308. Now each is a bad_request of at most 300
    characters, nothing is logged, and the session steps on, finite."""
    undisturbed = _undisturbed(good, server)
    good.begin("attacked")
    attacker = Raw(server.address)
    sent = 0
    log_before = server.log_bytes
    try:
        assert attacker.send(op="open", scene="membrane-live", session="bad")["ok"]
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and sent < 4000:
            for bad in _bad_values():
                message = _refused(attacker.send(**bad.message))
                assert "y" * 65 not in message, bad.what
                sent += 1
        after = attacker.send(
            op="step", scene="membrane-live", session="bad", k=0,
            probes=[{"at": [0.5, 0.5], "depth": 1e3, "radius": 10.0}],
        )  # fmt: skip
        assert after["ok"] and np.isfinite(after["probes"][0]["force"])
        z = np.frombuffer(after["z"]["data"], "<f4")
        assert np.isfinite(z).all()
    finally:
        attacker.close()
    during = good.begin("after")
    check_against_undisturbed(request, f"L4-L6 ({sent} bad values)", undisturbed, during)
    logged = server.log_bytes - log_before
    print(f"L4-L6: {sent} refusals wrote {logged} bytes of log")
    assert logged < 4096
    _survived(server, 32, "L4-L6")


# -- L7, L8: sessions are bound to their opener's key; retries told by the Session's token --------


@pytest.fixture
def keyed(tmp_path: Path) -> Iterator[tuple[WatchedServer, SocketOptions, SocketOptions]]:
    made = {}
    for name in ("server", "first", "second"):
        (tmp_path / name).mkdir()
        made[name] = create_keypair(tmp_path / name, name)
    allowed = tmp_path / "allowed"
    allowed.mkdir()
    for name in ("first", "second"):
        shutil.copy(made[name][0], allowed)
    server = WatchedServer(
        SCENES, ["--curve-secret", str(made["server"][1]), "--curve-clients", str(allowed)]
    )
    public = made["server"][0]
    first, second = (client_socket_options(public, made[k][1]) for k in ("first", "second"))
    yield server, first, second
    server.close()


def test_a_second_listed_key_cannot_use_the_first_keys_session(
    keyed: tuple[WatchedServer, SocketOptions, SocketOptions], request: pytest.FixtureRequest
) -> None:
    """With CurveZMQ a second listed key stepped, reset and closed the first key's session."""
    server, first_keys, second_keys = keyed
    good = LiveGoodClient(server.address, socket_options=first_keys).start()
    try:
        undisturbed = _undisturbed(good, server)
        good.begin("attacked")
        owner = Client(server.address, timeout=5.0, socket_options=first_keys)
        other = Client(server.address, timeout=5.0, socket_options=second_keys)
        with owner, other:
            session = owner.session("membrane-live")
            stranger = Session(other, "membrane-live", session.id)
            deadline, tries = time.monotonic() + 1.5, 0
            while time.monotonic() < deadline:
                for call in (stranger.step, stranger.frame, stranger.reset):
                    with pytest.raises(ServerError) as refused:
                        call()
                    assert refused.value.code == "unknown_session"
                closed = other.request("close", scene="membrane-live", session=session.id)
                assert closed["closed"] is False
                tries += 1
            assert session.step().k == 1  # the owner's session, untouched
        during = good.begin("after")
    finally:
        good.stop()
    check_against_undisturbed(request, f"L7 ({tries} x 4 ops by another key)", undisturbed, during)
    _survived(server, 32, "L7")


def test_two_clients_whose_request_ids_coincide_each_keep_their_own_steps(
    server: WatchedServer,
) -> None:
    """Every Client numbers its requests from 1: a second client stepping the same session id
    with the same k and request id was answered the first one's stored reply, as a re-send."""
    first, second = Client(server.address, timeout=5.0), Client(server.address, timeout=5.0)
    with first, second:
        mine = first.session("membrane-live")  # request 1 of the first client
        theirs = Session(second, "membrane-live", mine.id)
        with pytest.raises(ServerError) as refused:
            theirs.open()  # request 1 of the second: same id, another token
        assert refused.value.code == "session_exists"
        first.ping(), second.ping()
        assert mine.step(probes=[{"at": [0.5, 0.5], "depth": 1e-3, "radius": 0.05}]).k == 1
        with pytest.raises(ServerError) as refused:
            theirs.step()  # k = 0 and the same request id as the first's step: not a re-send
        assert refused.value.code == "step_mismatch"
        assert mine.frame().k == 1
