"""The live surface against inputs the protocol allows but a server must not be hurt by: the
real dispatcher in this process, the real Client and Session through the transport seam.

Each test is one of the defects found from outside (the numbers of docs/ROBUSTNESS.md's attack
table): sessions told apart by their token, bound to their CurveZMQ key and bounded per peer; a
session's memory within what ``describe`` says; every bad value a structured ``bad_request`` of
bounded length, never ``internal_error``; a reloaded dispatcher freed without a collection.
"""

from __future__ import annotations

import gc
import math
import tracemalloc
import weakref
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from membrane_client import Client, Probe, ServerError
from membrane_client import Load as WireLoad
from membrane_client.protocol import (
    MAX_ERROR_CHARS,
    MAX_LOADS,
    MAX_PROBES,
    ErrorCode,
    Request,
    decode,
    encode,
)
from membrane_client.session import Session
from membrane_models.live import Load, ModalEngine
from membrane_models.live import Probe as EngineProbe
from membrane_models.live.cost import step_cost
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.served import ServedScene
from membrane_server.sessions import SessionTable

LIVE_SCENES = ("membrane-live", "rope-live")


@pytest.fixture(scope="module")
def scenes() -> dict[str, ServedScene]:
    return {name: ServedScene.load(name) for name in LIVE_SCENES}


@pytest.fixture
def dispatcher(scenes: dict[str, ServedScene]) -> Dispatcher:
    return Dispatcher(list(scenes.values()), sessions=SessionTable(max_per_peer=4))


def _client(dispatcher: Dispatcher, peer: str = "") -> Client:
    return Client("in-process://live", transport=InProcessTransport(dispatcher, peer))


def _session(
    client: Client, scene: str, session_id: str | None = None, open: bool = True
) -> Session:
    session = Session(client, scene, session_id)
    return session.open() if open else session


def _refusal(call: Any, *args: Any, **kwargs: Any) -> ServerError:
    with pytest.raises(ServerError) as refused:
        call(*args, **kwargs)
    return refused.value


# -- re-sends told by the Session's token (defects 13 and 15) ---------------------------------


def test_two_sessions_whose_request_ids_coincide_are_never_taken_for_one_resending(
    dispatcher: Dispatcher,
) -> None:
    """Two Clients number their requests alike (1, 2, ...): the second's open of the same id
    and its step of the same k and request id were answered with the first's stored replies."""
    first, second = _client(dispatcher), _client(dispatcher)
    a = _session(first, "membrane-live", "shared")  # request 1 of its client
    joined = _session(second, "membrane-live", "shared", open=False)
    assert _refusal(joined.open).code == ErrorCode.SESSION_EXISTS  # also request 1
    first.ping(), second.ping()  # request 2 of each: the two clients' ids stay aligned
    stepped = a.step(probes=[Probe((0.5, 0.5), 0.001, 0.05)])  # request 3, k = 0
    assert stepped.k == 1
    joined.k = 0  # the second client's step k = 0, request 3: the same id, k and op
    refused = _refusal(joined.step, probes=[Probe((0.5, 0.5), 0.002, 0.05)])
    assert refused.code == ErrorCode.STEP_MISMATCH
    assert a.frame().k == 1  # nothing was applied twice, nothing of the second applied


def test_an_open_is_recognised_as_resent_by_token_and_scene_not_request_id(
    dispatcher: Dispatcher,
) -> None:
    """An open of id x on membrane-live with the id of an earlier open on rope-live got
    rope-live's stored ok; the next read failed with "this session is on scene rope-live"."""
    rope = _client(dispatcher)
    _session(rope, "rope-live", "x")
    other = _client(dispatcher)  # its first request has rope's open's request id
    refused = _refusal(_session, other, "membrane-live", "x")
    assert refused.code == ErrorCode.SESSION_EXISTS
    first_open = Request("open", 1, "x", scene="rope-live").to_wire()  # no token: by request id
    assert decode(dispatcher.handle([first_open]).reply)["error"]["code"] == "session_exists"


def test_a_lost_step_reply_resent_by_its_own_session_is_answered_from_the_store(
    dispatcher: Dispatcher,
) -> None:
    client = _client(dispatcher)
    session = client.session("membrane-live")
    session.step(loads=[WireLoad((0.5, 0.5), 0.1, 0.05)])
    resend = Request(
        "step", 99, session.id, scene="membrane-live", k=0, token=session.token,
        loads=[{"at": [0.5, 0.5], "force": 0.1, "radius": 0.05}],
    )  # fmt: skip
    reply = decode(dispatcher.handle([resend.to_wire()]).reply)
    assert reply["ok"] and reply["k"] == 1  # the stored reply (its own id), not a new step
    read = client.request("read", scene="membrane-live", session=session.id)
    assert read["k"] == 1 and read["token"] == session.token  # whose step the state follows


# -- sessions bound to their key, bounded per peer (defects 5 and 14) -------------------------


def test_a_session_opened_with_a_curve_key_is_that_keys_alone(dispatcher: Dispatcher) -> None:
    owner, other = _client(dispatcher, "key:A"), _client(dispatcher, "key:B")
    session = owner.session("membrane-live")
    stranger = _session(other, "membrane-live", session.id, open=False)
    stranger.k = 0
    for call in (stranger.step, stranger.frame, stranger.reset):
        assert _refusal(call).code == ErrorCode.UNKNOWN_SESSION
    assert other.request("close", scene="membrane-live", session=session.id)["closed"] is False
    assert _refusal(stranger.open).code == ErrorCode.SESSION_EXISTS  # taken, nothing more said
    assert session.step().k == 1  # still the owner's, untouched


def test_without_keys_a_session_id_is_a_bearer_token(dispatcher: Dispatcher) -> None:
    session = _client(dispatcher, "conn:01").session("membrane-live")
    joined = _session(_client(dispatcher, "conn:02"), "membrane-live", session.id, open=False)
    assert joined.step().k == 1  # documented: without keys, whoever knows the id may use it


def test_one_peer_cannot_take_every_session(dispatcher: Dispatcher) -> None:
    """One DEALER opened all 64 sessions and kept them alive; now a peer holds at most
    ``max_per_peer`` (4 here), and other peers still open theirs."""
    greedy = _client(dispatcher, "key:greedy")
    held = [greedy.session("rope-live") for _ in range(4)]
    refused = _refusal(greedy.session, "rope-live")
    assert refused.code == ErrorCode.TOO_MANY_SESSIONS and "this peer holds 4" in refused.message
    assert _client(dispatcher, "key:polite").session("rope-live").step().k == 1
    held[0].close()
    assert greedy.session("rope-live").step().k == 1  # a freed place is the peer's again
    assert dispatcher.sessions.snapshot()["max_per_peer"] == 4


# -- a session's memory within what describe says ---------------------------------------------


def _worst_legal_step(engine: ModalEngine) -> tuple[list[WireLoad], list[Probe]]:
    """The accepted step that holds the most spectra: the most loads and probes at the
    smallest radius the budget lets through."""
    dims = engine.spatial_dims
    best: tuple[int, list[WireLoad], list[Probe]] = (-1, [], [])
    for factor in (1, 2, 4, 8, 16, 32, 64, 128):
        radius = engine.min_radius * factor
        for count in (MAX_LOADS, 32, 16, 8, 4, 2, 1):
            load_at = [(0.2 + 0.6 * i / MAX_LOADS,) * dims for i in range(count)]
            probe_at = [(0.1 + 0.1 * j,) * dims for j in range(MAX_PROBES)]
            loads = [WireLoad(a, 1.0, radius) for a in load_at]
            probes = [Probe(a, 1e-3, radius) for a in probe_at]
            sizes = [engine.footprint_size(Load(a, 1.0, radius), "load", 0) for a in load_at]
            inside = [
                engine.footprint_size(EngineProbe(a, 0.0, radius), "probe", 0) for a in probe_at
            ]
            cost = step_cost(sizes, inside, engine.lattice_shape, True)
            within = cost.work <= engine.budget.max_work
            held = cost.held_bytes
            if within and held <= engine.budget.max_held_bytes and held > best[0]:
                best = (held, loads, probes)
    assert best[0] > 0
    return best[1], best[2]


@pytest.mark.parametrize("name", LIVE_SCENES)
def test_session_bytes_bounds_a_sessions_measured_memory(
    scenes: dict[str, ServedScene], name: str
) -> None:
    """tracemalloc's growth over an open and the worst legal step (with its frame, the reply
    stored) stays below ``describe``'s ``session_bytes``; rope-live's 64 loads at its
    min_radius held about 124 MiB against the 8,416 bytes claimed."""
    served = scenes[name]
    engine = served.live
    assert isinstance(engine, ModalEngine)
    loads, probes = _worst_legal_step(engine)
    client = _client(Dispatcher([served], sessions=SessionTable()))
    claimed = client.describe(name).live["session_bytes"]
    engine_loads = [Load(*load) for load in loads]
    engine_probes = [EngineProbe(*probe) for probe in probes]
    engine.step(engine.start().state, engine_loads, engine_probes)  # tables, caches grown first
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        session = client.session(name)
        session.step(loads, probes, frame=True)
        del session  # the client's objects go; the server's session stays open
        gc.collect()
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    print(f"{name}: a session holds {held} bytes after its worst legal step; claimed {claimed}")
    assert 0 < held <= claimed


# -- bad values: a structured bad_request within the length bound (defects 6, 10, 11) --------


def _array(dtype: Any, shape: Any, data: bytes) -> dict[str, Any]:
    return {"dtype": dtype, "shape": shape, "data": data}


def _bad_requests() -> Iterator[tuple[str, dict[str, Any]]]:
    def step(**fields: Any) -> dict[str, Any]:
        return {"op": "step", "scene": "membrane-live", "k": 0, **fields}

    def load(radius: float = 0.05, force: Any = 1.0) -> dict[str, Any]:
        return {"at": [0.5, 0.5], "force": force, "radius": radius}

    def probe(depth: Any = 1e-3, radius: float = 0.05, at: Any = None) -> dict[str, Any]:
        return {"at": at if at is not None else [0.5, 0.5], "depth": depth, "radius": radius}

    def open_with(array: dict[str, Any]) -> dict[str, Any]:
        return {"op": "open", "scene": "membrane-live", "initial": {"displacement": array}}

    yield "radius 1e-320", step(loads=[load(1e-320)])
    yield "radius 5e-324", step(probes=[probe(radius=5e-324)])
    yield "radius 1e9", step(loads=[load(1e9)])
    yield "64 loads at min_radius", step(loads=[load(0.00390625)] * MAX_LOADS)
    yield "depth 1e308", step(probes=[probe(1e308)])
    yield "depth true", step(probes=[probe(True)])
    yield "force 2^63", step(loads=[load(force=2**63)])
    yield "force 1e308", step(loads=[load(force=1e308)])
    yield "at of 7000", step(probes=[probe(at=[0.5] * 7000)])
    yield "65 axes", open_with(_array("<f4", [1] * 65, b"\0" * 4))
    yield "a 4,400-digit product", open_with(_array("<f4", [2**63 - 1] * 230, b""))
    yield "huge product", open_with(_array("<f4", [2**62, 2**62, 4], b"\0" * 16))
    yield "100,000-character dtype", open_with(_array("x" * 100_000, [400], b"\0" * 1600))
    yield "initial 1e308", open_with(_array("<f8", [400], np.full(400, 1e308).tobytes()))
    yield "initial 3e38", open_with(_array("<f4", [400], np.full(400, 3e38, "<f4").tobytes()))


@pytest.mark.parametrize(
    ("what", "fields"), [pytest.param(what, fields, id=what) for what, fields in _bad_requests()]
)
def test_every_bad_value_is_a_bad_request_of_bounded_length(
    dispatcher: Dispatcher, what: str, fields: dict[str, Any]
) -> None:
    session = f"s-{abs(hash(what)) % 10**9}"
    if fields["op"] == "step":
        opened = encode({"v": 1, "id": 1, "op": "open", "scene": "membrane-live",
                         "session": session})  # fmt: skip
        assert decode(dispatcher.handle([opened]).reply)["ok"]
    message = encode({"v": 1, "id": 2, "session": session, **fields})
    answer = dispatcher.handle([message])
    reply = decode(answer.reply)
    assert reply["ok"] is False, what
    error = reply["error"]
    assert error["code"] in ("bad_request", "bad_message"), (what, error)
    assert len(error["message"]) <= MAX_ERROR_CHARS, (what, len(error["message"]))
    assert "x" * 65 not in error["message"]  # at most 64 characters of a client's value
    if fields["op"] == "step":  # the session is unpoisoned: the next good step is finite
        good = encode({"v": 1, "id": 3, "session": session, **{**fields, "loads": [],
                                                                 "probes": []}})  # fmt: skip
        stepped = decode(dispatcher.handle([good]).reply)
        assert stepped["ok"] and stepped["k"] == 1


def test_no_accepted_step_leaves_inf_or_nan(dispatcher: Dispatcher) -> None:
    """The largest accepted depth, force and radius give finite forces and frames (before:
    depth 1e308 gave force inf and NaN frames until reset, with ok: true)."""
    live = dispatcher.scenes["membrane-live"].live
    assert isinstance(live, ModalEngine)
    limits: dict[str, Any] = live.describe()
    session = _client(dispatcher).session("membrane-live")
    deepest = Probe((0.5, 0.5), float(limits["max_depth"]), float(limits["max_radius"]))
    strongest = WireLoad((0.5, 0.5), float(limits["max_force"]), live.min_radius * 2)
    for _ in range(3):
        frame = session.step(loads=[strongest], probes=[deepest])
        assert frame.z is not None and np.isfinite(frame.z).all()
        assert all(math.isfinite(p.force) for p in frame.probes)


# -- reloads free the old scenes without a collection (defect 4) ------------------------------


def test_a_replaced_dispatcher_and_its_scenes_are_freed_by_reference_counting() -> None:
    """The old Dispatcher sat in a reference cycle (its op table held its own bound methods,
    the live ops its bound scene lookup): +83 MiB per SIGHUP until a full collection."""
    served = ServedScene.load("membrane-live")
    table = SessionTable()
    dispatcher = Dispatcher([served], sessions=table)
    dispatcher.handle([Request("hello", 1).to_wire()])
    old_dispatcher, old_scene = weakref.ref(dispatcher), weakref.ref(served)
    gc.disable()
    try:
        del dispatcher, served
        assert old_dispatcher() is None and old_scene() is None
    finally:
        gc.enable()


@pytest.mark.slow
def test_an_old_scene_lives_exactly_as_long_as_a_session_holds_it() -> None:
    served = ServedScene.load("membrane-live")
    table = SessionTable()
    client = _client(Dispatcher([served], sessions=table))
    session_id = client.session("membrane-live").id
    old_scene = weakref.ref(served)
    Dispatcher([ServedScene.load("membrane-live")], sessions=table)  # the reload's
    del served, client
    gc.disable()
    try:
        assert old_scene() is not None  # the open session still steps on it
        table.close(session_id)
        assert old_scene() is None
    finally:
        gc.enable()


def test_a_resend_numbered_anew_gets_the_stored_reply_under_its_own_id(
    dispatcher: Dispatcher,
) -> None:
    """A client that retries with a new request id (not the Lazy Pirate's same bytes) must get
    a reply its id check accepts: the stored one, re-addressed, never applied twice."""
    session = _session(_client(dispatcher), "membrane-live")
    step = Request("step", 500, session.id, scene="membrane-live", k=0, token=session.token)
    first = decode(dispatcher.handle([step.to_wire()]).reply)
    step.id = 501
    again = decode(dispatcher.handle([step.to_wire()]).reply)
    assert first["id"] == 500 and again["id"] == 501
    assert {**again, "id": 500} == first  # the same step, not a second one
    reopen = Request("open", 502, session.id, scene="membrane-live", token=session.token)
    reopened = decode(dispatcher.handle([reopen.to_wire()]).reply)
    assert reopened["ok"] and reopened["id"] == 502 and reopened["k"] == 0
