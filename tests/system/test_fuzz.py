"""Protocol fuzzing: hypothesis against the codec, the dispatcher, and a live server.

Every input is checked against the spec (docs/PROTOCOL.md), not only for "no crash": a request
gets exactly one reply; the reply is ``ok`` exactly when no rule of the envelope or the op is
broken, and otherwise carries one of the codes those broken rules call for; an ``ok`` query
carries the very frame the scene serves for that time. Oversized messages are dropped with their
connection. While the live server is fuzzed, a well-behaved client polls it and checks every
frame it gets.

The number of inputs tried is printed at the end of the module (``fuzz inputs tried: ...``).
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import msgpack
import numpy as np
import pytest
import zmq
from attackers import dealer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reporting import print_past_capture

from membrane_client import Client
from membrane_client.errors import ProtocolError
from membrane_client.protocol import (
    ARRAY_DTYPES,
    MAX_BATCH_STEPS,
    MAX_REQUEST_BYTES,
    MAX_SESSION_CHARS,
    PROTOCOL_VERSION,
    ErrorCode,
    Op,
    Request,
    decode,
    encode,
    unpack_array,
)
from membrane_server.dispatch import Dispatcher
from membrane_server.scene import scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.server import Server

# Inputs tried, per kind, and the good client's correct answers (printed at the end).
TALLY: Counter[str] = Counter()
GOOD_QUERIES: Counter[str] = Counter()


# MEMBRANE_FUZZ_SCALE=10 multiplies every example count (a longer hunt, outside the suite).
FUZZ_SCALE = max(1, int(os.environ.get("MEMBRANE_FUZZ_SCALE", "1")))


def fuzz(max_examples: int) -> settings:
    """Hypothesis settings for this module: a modest, fixed number of examples, no deadline
    (a shared 2-core machine: timing says nothing here), nothing stored between runs."""
    return settings(
        max_examples=max_examples * FUZZ_SCALE,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
        database=None,
    )


REPLY_TIMEOUT_MS = 5000

# -- strategies -------------------------------------------------------------------------------

MISSING = object()  # a field left out of the request
SCENE_NAMES = ["network", "separable", "table", "exact", "edge"]
EDGE_DURATION = 0.5

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),  # everything msgpack can carry
    st.floats(),  # NaN, infinities, subnormals, -0.0 included
    st.text(max_size=20),
    st.binary(max_size=20),
    st.builds(msgpack.ExtType, st.integers(0, 127), st.binary(max_size=8)),
)
anything = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=4), st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=10,
)
times = st.one_of(
    st.floats(-0.2, 1.2),
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(-(2**63), 2**63 - 1),
    st.sampled_from([0.0, -0.0, 0.5, 1.0, 1e9, -1e-12, 1.7976931348623157e308, 5e-324]),
)
FIELDS = ("v", "id", "op", "scene", "t", "dtype", "session")
VALID: dict[str, st.SearchStrategy[Any]] = {
    "v": st.just(1),
    "id": st.integers(0, 2**63 - 1),
    # Queries are where most rules live; opens reach the live refusals (every scene is a film).
    "op": st.sampled_from([str(Op.QUERY)] * 8 + [str(Op.OPEN)] * 2 + [str(op) for op in Op]),
    "scene": st.sampled_from(["edge", *SCENE_NAMES]),  # 'edge' twice: its policy is 'error'
    "t": times,
    "dtype": st.one_of(st.sampled_from(ARRAY_DTYPES), st.just(MISSING)),
    "session": st.one_of(st.text(max_size=MAX_SESSION_CHARS), st.just(MISSING)),
}
INVALID: dict[str, st.SearchStrategy[Any]] = {
    "v": st.one_of(st.integers(-3, 3), st.just(True), anything),
    "id": st.one_of(st.integers(-(2**63), -1), st.integers(2**63, 2**64 - 1), anything),
    "op": st.one_of(st.text(max_size=12), st.text(max_size=12), anything),
    "scene": st.one_of(st.text(max_size=12), anything),
    "t": st.one_of(*[st.sampled_from([math.nan, math.inf, -math.inf])] * 2, anything),
    "dtype": st.one_of(st.sampled_from(["<f2", ">f4", "float32", "<i4"]), anything),
    "session": st.one_of(st.text(min_size=MAX_SESSION_CHARS + 1, max_size=100), anything),
}


@st.composite
def requests(draw: st.DrawFn) -> dict[str, Any]:
    """A request map with none, one or a few fields broken (wrong type, value, or left out)
    and perhaps unknown extra fields: every rule gets reached, alone or with others."""
    broken = draw(
        st.one_of(st.just(set()), st.sets(st.sampled_from(FIELDS), min_size=1, max_size=3))
    )
    message: dict[str, Any] = draw(
        st.dictionaries(st.text(max_size=10).filter(lambda k: k not in FIELDS), anything,
                        max_size=2)
    )  # fmt: skip
    for key in FIELDS:
        strategy = st.one_of(INVALID[key], st.just(MISSING)) if key in broken else VALID[key]
        value = draw(strategy)
        if value is not MISSING:
            message[key] = value
    return message


@st.composite
def payloads(draw: st.DrawFn) -> bytes:
    """One message frame: a request map, or bytes that are not one."""
    kind = draw(st.sampled_from(["request"] * 8 + ["bytes", "truncated", "not a map", "keys"]))
    if kind == "request":
        return encode(draw(requests()))
    if kind == "bytes":
        return draw(st.binary(max_size=200))
    if kind == "truncated":
        data = encode(draw(requests()))
        return data[: draw(st.integers(0, max(0, len(data) - 1)))]
    if kind == "not a map":
        value = draw(anything.filter(lambda v: not isinstance(v, dict)))
        packed: bytes = msgpack.packb(value, use_bin_type=True)
        return packed
    keys = st.one_of(st.integers(-5, 5), st.binary(max_size=4), st.booleans())
    packed = msgpack.packb(draw(st.dictionaries(keys, anything, min_size=1, max_size=3)))
    return packed


single_frames = payloads().map(lambda payload: [payload])
bodies = st.one_of(  # mostly one frame (as the protocol wants), sometimes several or none
    *[single_frames] * 4,
    st.lists(st.one_of(payloads(), st.binary(max_size=30)), min_size=0, max_size=5),
)

# -- the oracle: what the spec says the reply must be --------------------------------------------


def expected_errors(body: list[bytes], scenes: dict[str, ServedScene]) -> tuple[set[str], Any]:
    """The error codes the spec allows for this request (empty: it must succeed), and its id."""
    if len(body) != 1:
        return {ErrorCode.BAD_MESSAGE}, None
    try:
        message = decode(body[0])
    except ProtocolError:
        return {ErrorCode.BAD_MESSAGE}, None
    broken: set[str] = set()
    request_id: Any = message.get("id")
    plain_int = isinstance(request_id, int) and not isinstance(request_id, bool)
    if not (plain_int and 0 <= request_id < 2**63):
        broken.add(ErrorCode.BAD_REQUEST)
        request_id = None
    version = message.get("v")
    if type(version) is not int or version != 1:  # 1.0 and True are not version 1
        broken.add(ErrorCode.BAD_VERSION)
    op, session = message.get("op"), message.get("session")
    if session is not None and not (isinstance(session, str) and len(session) <= 64):
        broken.add(ErrorCode.BAD_REQUEST)
    if not isinstance(op, str):
        broken.add(ErrorCode.BAD_REQUEST)
    elif op not in list(Op):
        broken.add(ErrorCode.UNKNOWN_OP)
    elif op in (Op.DESCRIBE, Op.QUERY):
        broken |= _scene_errors(message, scenes)
        if op == Op.QUERY:
            broken |= _query_errors(message, scenes)
    elif op in LIVE_OPS:
        broken |= _live_errors(op, message, scenes)
    elif op == Op.STEPS:
        broken |= _steps_errors(message)
    elif op == Op.STEP_COLUMNS:
        broken |= _columns_errors(message, scenes)
    return broken, request_id


LIVE_OPS = (Op.OPEN, Op.STEP, Op.READ, Op.RESET, Op.CLOSE)


def _live_errors(op: str, message: dict[str, Any], scenes: dict[str, ServedScene]) -> set[str]:
    """Every scene here is a film and no session is ever open: a live op is refused, but
    ``close``, which is harmless on a session that is not open (PROTOCOL.md, "Live sessions")."""
    name = message.get("scene")
    if not isinstance(message.get("session"), str) or not isinstance(name, str | None):
        return {ErrorCode.BAD_REQUEST}
    if op in (Op.STEP, Op.READ) and message.get("dtype", "<f4") not in ARRAY_DTYPES:
        return {ErrorCode.BAD_REQUEST}  # their replies carry a frame: its dtype is read first
    if op == Op.OPEN:
        return _scene_errors(message, scenes) or {ErrorCode.NOT_LIVE}
    if op == Op.STEP:
        return {ErrorCode.BAD_REQUEST}  # the fuzzer sends no 'k'
    return set() if op == Op.CLOSE else {ErrorCode.UNKNOWN_SESSION}


def _steps_errors(message: dict[str, Any]) -> set[str]:
    """A ``steps`` batch (PROTOCOL.md): refused whole when its scene is not a name or its
    ``steps`` not a list of 1 to MAX_BATCH_STEPS items whose repeats stay within that bound;
    otherwise answered ok, each item's own refusal inside it."""
    items = message.get("steps")
    if not isinstance(message.get("scene"), str | None):
        return {ErrorCode.BAD_REQUEST}
    if type(items) is not list or not 1 <= len(items) <= MAX_BATCH_STEPS:
        return {ErrorCode.BAD_REQUEST}
    repeats = [
        item.get("repeat", 1) if type(item) is dict and type(item.get("repeat", 1)) is int else 1
        for item in items
    ]
    return {ErrorCode.BAD_REQUEST} if sum(repeats) > MAX_BATCH_STEPS else set()


def _columns_errors(message: dict[str, Any], scenes: dict[str, ServedScene]) -> set[str]:
    """A ``step_columns`` request (PROTOCOL.md): refused whole when its columns are out of
    form; columns in form reach the scene, a film here (or none named, or an unknown one)."""
    sessions = message.get("sessions")
    in_form = (
        isinstance(message.get("scene"), str | None)
        and message.get("dtype", "<f4") in ARRAY_DTYPES
        and type(sessions) is list
        and 1 <= len(sessions) <= MAX_BATCH_STEPS
        and all(type(s) is str and len(s) <= 64 for s in sessions)
        and len(set(sessions)) == len(sessions)
    )
    if not in_form:
        return {ErrorCode.BAD_REQUEST}
    # k, tokens, frames and the loads' array are checked next: refused, or on to the scene.
    return {ErrorCode.BAD_REQUEST, ErrorCode.NOT_LIVE} | _scene_errors(message, scenes)


def _scene_errors(message: dict[str, Any], scenes: dict[str, ServedScene]) -> set[str]:
    name = message.get("scene")
    if name is None or (isinstance(name, str) and name not in scenes):
        return {ErrorCode.UNKNOWN_SCENE}  # several scenes hosted: a name is required
    return set() if isinstance(name, str) else {ErrorCode.BAD_REQUEST}


def _query_errors(message: dict[str, Any], scenes: dict[str, ServedScene]) -> set[str]:
    broken: set[str] = set()
    t = message.get("t", MISSING)
    if message.get("dtype", "<f4") not in ARRAY_DTYPES:
        broken.add(ErrorCode.BAD_REQUEST)
    if t is MISSING or isinstance(t, bool) or not isinstance(t, int | float):
        return broken | {ErrorCode.BAD_REQUEST}
    if not math.isfinite(t):
        return broken | {ErrorCode.INVALID_TIME}
    name = message.get("scene")
    served = scenes.get(name) if isinstance(name, str) else None
    if served is not None and served.scene.policy == "error":
        # The spec's step position; under linear snapping there are no half steps to round.
        timeline = served.timeline
        position = (float(t) - timeline.start_offset) / timeline.dt
        # Within rounding of a step is on it (PROTOCOL.md, "Time"): 8 epsilons of the magnitudes.
        scale = (abs(float(t)) + abs(timeline.start_offset)) / timeline.dt + abs(position)
        if math.isfinite(position) and abs(position - round(position)) <= 8 * 2.0**-52 * scale:
            position = float(round(position))
        if not 0.0 <= position <= timeline.last_step:
            broken.add(ErrorCode.OUT_OF_DOMAIN)
    return broken


def check_reply(body: list[bytes], reply_bytes: bytes, scenes: dict[str, ServedScene]) -> str:
    """Assert the reply is what the spec allows; returns its code ("ok" for success)."""
    reply = decode(reply_bytes)
    allowed, request_id = expected_errors(body, scenes)
    assert reply["v"] == 1 and isinstance(reply["ok"], bool)
    assert reply["id"] == request_id
    if not reply["ok"]:
        error = reply["error"]
        assert error["code"] in allowed, (error, allowed)
        assert isinstance(error["message"], str) and error["message"]
        assert "\n" not in error["message"]
        return str(error["code"])
    assert not allowed, f"answered ok although it breaks {allowed}"
    message = decode(body[0])
    if message["op"] == Op.QUERY:
        _check_frame(message, reply, scenes[message["scene"]])
    elif message["op"] == Op.DESCRIBE:
        served = scenes[message["scene"]]
        assert reply["shape"] == list(served.shape)
        assert unpack_array(reply["points"]).shape[0] == served.evaluator.n_points
    elif message["op"] == Op.PING:
        assert reply["pong"] is True
    elif message["op"] == Op.HELLO:
        assert sorted(reply["scenes"]) == sorted(scenes)
    elif message["op"] == Op.CLOSE:
        assert reply["closed"] is False
    elif message["op"] == Op.STEPS:
        assert len(reply["steps"]) == len(message["steps"])
    return "ok"


def _check_frame(message: dict[str, Any], reply: dict[str, Any], served: ServedScene) -> None:
    t = float(message["t"])
    sample = served.timeline.resolve(t)
    assert (reply["step"], reply["t"], reply["domain"]) == (sample.step, sample.t, sample.domain)
    # Times are float64 in the server: an int t beyond 2^53 comes back as its float64 value.
    assert reply["requested_t"] == float(message["t"])
    dtype = message.get("dtype", "<f4")
    z = unpack_array(reply["z"])
    expected = served.frame(sample).reshape(served.shape).astype(np.dtype(dtype))
    assert z.dtype == np.dtype(dtype) and z.shape == served.shape
    np.testing.assert_array_equal(z, expected)


# -- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module", autouse=True)
def report_tally(request: pytest.FixtureRequest) -> Iterator[None]:
    """Print how many inputs each fuzz test tried, once the module is done."""
    yield
    if not TALLY:
        return
    counts = ", ".join(f"{name} {count}" for name, count in sorted(TALLY.items()))
    line = f"\nfuzz inputs tried: {counts} (total {sum(TALLY.values())})"
    if GOOD_QUERIES:
        line += f"; a good client got {GOOD_QUERIES['ok']} right frames meanwhile"
    print_past_capture(request, line)


@pytest.fixture(scope="module")
def scenes(evaluator_scenes: dict[str, ServedScene]) -> dict[str, ServedScene]:
    """The four evaluators (policy hold) plus 'edge': policy error, linear snapping."""
    edge = scene_from_dict(
        {"name": "edge", "model": "string-forced", "evaluator": "exact", "lattice": {"nx": 7},
         "dt": 0.01, "duration": EDGE_DURATION, "policy": "error", "snapping": "linear"}
    )  # fmt: skip
    return {**evaluator_scenes, "edge": ServedScene.load(edge)}


@pytest.fixture(scope="module")
def running_server(scenes: dict[str, ServedScene]) -> Iterator[Server]:
    server = Server(list(scenes.values()), bind="tcp://127.0.0.1:*")
    server.start()
    yield server
    server.stop()


class GoodClient:
    """A well-behaved client polling the server in a thread, checking every frame it gets."""

    def __init__(self, address: str, served: ServedScene) -> None:
        self.queries = 0
        self.failures: list[str] = []
        self._served = served
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(address,), daemon=True)
        self._thread.start()

    def _run(self, address: str) -> None:
        try:
            with Client(address, timeout=5.0, scene=self._served.name) as client:
                while not self._stop.is_set():
                    step = self.queries % (self._served.timeline.last_step + 1)
                    frame = client.query(step * 0.01)
                    expected = self._served.evaluator.frame(step * 0.01).astype(np.float32)
                    if frame.step != step or not np.array_equal(frame.z.reshape(-1), expected):
                        self.failures.append(f"wrong frame for step {step}")
                    self.queries += 1
                    time.sleep(0.001)
        except Exception as exc:  # any failure of the good client fails the test
            self.failures.append(repr(exc))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)
        assert not self._thread.is_alive()


def _dealer(address: str) -> zmq.Socket[bytes]:
    return dealer(address, REPLY_TIMEOUT_MS)


# -- the codec --------------------------------------------------------------------------------


@pytest.mark.slow
@fuzz(300)
@given(message=requests(), data=st.data())
def test_every_strict_prefix_of_a_message_is_refused(message: dict[str, Any], data: Any) -> None:
    encoded = encode(message)
    assert encode(decode(encoded)) == encoded  # the whole message reads back as it was
    cut = data.draw(st.integers(0, len(encoded) - 1))
    TALLY["codec"] += 1
    with pytest.raises(ProtocolError):
        decode(encoded[:cut])


@fuzz(300)
@given(data=st.binary(max_size=300))
def test_random_bytes_decode_to_a_map_or_a_protocol_error(data: bytes) -> None:
    TALLY["codec"] += 1
    try:
        message = decode(data)
    except ProtocolError:
        return
    assert isinstance(message, dict) and all(isinstance(key, str) for key in message)


# -- the dispatcher (no sockets: many inputs) -----------------------------------------------------


@pytest.mark.slow
@fuzz(500)
@given(body=bodies)
def test_dispatcher_answers_everything_by_the_spec(
    body: list[bytes], scenes: dict[str, ServedScene]
) -> None:
    dispatcher = _dispatcher(scenes)
    answer = dispatcher.handle(body)  # never raises
    TALLY["dispatcher"] += 1
    assert check_reply(body, answer.reply, scenes) != ErrorCode.INTERNAL_ERROR


_DISPATCHERS: dict[int, Dispatcher] = {}


def _dispatcher(scenes: dict[str, ServedScene]) -> Dispatcher:
    key = id(scenes)
    if key not in _DISPATCHERS:
        _DISPATCHERS[key] = Dispatcher(list(scenes.values()))
    return _DISPATCHERS[key]


@pytest.mark.slow
def test_the_fuzzer_reaches_every_outcome(scenes: dict[str, ServedScene]) -> None:
    """Guards the generator: each error code and success is produced, so none goes untested."""
    seen: Counter[str] = Counter()

    @settings(fuzz(1000), derandomize=True)  # the same inputs every run: no flicker
    @given(body=bodies)
    def collect(body: list[bytes]) -> None:
        seen[check_reply(body, _dispatcher(scenes).handle(body).reply, scenes)] += 1

    collect()
    TALLY["dispatcher"] += sum(seen.values())
    # A live session's own refusals need one open: tests/server/test_live_sessions.py has them.
    stateful = {ErrorCode.SESSION_EXISTS, ErrorCode.STEP_MISMATCH, ErrorCode.TOO_MANY_SESSIONS}
    wanted = {str(code) for code in ErrorCode} - {ErrorCode.INTERNAL_ERROR, *stateful} | {"ok"}
    assert wanted <= set(seen), f"never produced: {wanted - set(seen)}"


# -- a live server ----------------------------------------------------------------------------


@pytest.mark.slow
@fuzz(150)
@given(body=bodies)
def test_live_server_answers_garbage_while_a_good_client_polls(
    body: list[bytes], running_server: Server, scenes: dict[str, ServedScene], good: GoodClient
) -> None:
    socket = _shared_dealer(running_server.address)
    socket.send_multipart([b"", *body])  # the empty delimiter REQ would add
    frames = socket.recv_multipart()  # zmq.Again (a missing reply) fails the test
    TALLY["live"] += 1
    assert frames[0] == b"" and len(frames) == 2
    check_reply(body, frames[1], scenes)


_SOCKETS: dict[str, zmq.Socket[bytes]] = {}


def _shared_dealer(address: str) -> zmq.Socket[bytes]:
    """One DEALER for the whole fuzz run: replies come back in order on one connection."""
    if address not in _SOCKETS:
        _SOCKETS[address] = _dealer(address)
    return _SOCKETS[address]


@pytest.fixture(scope="module")
def good(running_server: Server, scenes: dict[str, ServedScene]) -> Iterator[GoodClient]:
    client = GoodClient(running_server.address, scenes["table"])
    yield client
    client.stop()
    for socket in _SOCKETS.values():
        socket.close(linger=0)
    _SOCKETS.clear()
    assert client.failures == []
    assert client.queries > 0


@pytest.mark.slow
def test_the_good_client_was_served_throughout(good: GoodClient, running_server: Server) -> None:
    """Runs after the live fuzz (same module fixture): the poller never saw a wrong frame."""
    deadline = time.monotonic() + 5
    start = good.queries
    while good.queries < start + 10 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert good.failures == []
    assert good.queries >= start + 10
    GOOD_QUERIES["ok"] = good.queries


@pytest.mark.slow
@pytest.mark.parametrize(
    ("size", "answered"),
    [(MAX_REQUEST_BYTES - 1, True), (MAX_REQUEST_BYTES, True), (MAX_REQUEST_BYTES + 1, False),
     (10 * MAX_REQUEST_BYTES, False)],
)  # fmt: skip
def test_oversized_requests_drop_their_connection_only(
    running_server: Server, good: GoodClient, size: int, answered: bool
) -> None:
    payload = _ping_of_size(size)
    socket = _dealer(running_server.address)
    socket.setsockopt(zmq.RCVTIMEO, 1000 if not answered else REPLY_TIMEOUT_MS)
    try:
        socket.send_multipart([b"", payload])
        TALLY["oversize"] += 1
        if answered:
            reply = decode(socket.recv_multipart()[-1])
            assert (reply["ok"], reply["id"], reply["pong"]) == (True, 5, True)
        else:
            with pytest.raises(zmq.Again):
                socket.recv_multipart()
    finally:
        socket.close(linger=0)
    with Client(running_server.address, timeout=5.0) as client:  # the server is fine
        assert client.ping() > 0
    assert good.failures == []


def _ping_of_size(size: int) -> bytes:
    """A valid ping request exactly ``size`` bytes long (padded with an unknown field)."""
    padding = size
    for _ in range(4):  # the bin header grows from 3 to 5 bytes at 64 KiB: converge on it
        ping = {"v": PROTOCOL_VERSION, "id": 5, "op": "ping", "padding": b"\x00" * padding}
        payload = encode(ping)
        if len(payload) == size:
            return payload
        padding -= len(payload) - size
    raise AssertionError(f"cannot build a {size}-byte request")


@pytest.mark.slow
def test_multi_frame_garbage_near_and_over_the_size_limit(
    running_server: Server, good: GoodClient
) -> None:
    """The limit is per frame: many frames under it are one bad_message reply; one over it
    drops the whole message and its connection."""
    socket = _dealer(running_server.address)
    try:
        socket.send_multipart([b"", *([b"\xc1" * (MAX_REQUEST_BYTES // 2)] * 6)])
        reply = decode(socket.recv_multipart()[-1])
        assert reply["error"]["code"] == "bad_message" and reply["id"] is None
        socket.send_multipart([b"", *([b""] * 1000)])
        assert decode(socket.recv_multipart()[-1])["error"]["code"] == "bad_message"
        socket.send_multipart(
            [b"", Request("ping", 1).to_wire(), b"\x00" * (MAX_REQUEST_BYTES + 1)]
        )
        socket.setsockopt(zmq.RCVTIMEO, 1000)
        with pytest.raises(zmq.Again):
            socket.recv_multipart()
        TALLY["oversize"] += 3
    finally:
        socket.close(linger=0)
    with Client(running_server.address, timeout=5.0) as client:
        assert client.ping() > 0
    assert good.failures == []
