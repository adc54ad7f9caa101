"""The protocol, version 1: one msgpack map per message (spec: docs/PROTOCOL.md).

Both sides use this module: the client to build requests and read replies, the server to read
requests and build replies. The codec under it (bounded decode, arrays, previews) is ``codec``,
re-exported here; the live session's items and replies are ``live_schema``'s. It depends on
msgpack and numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, NoReturn

import msgpack

from membrane_client.codec import (
    ARRAY_DTYPES,
    MAX_ARRAY_DIMS,
    MAX_NESTING,
    MAX_REPLY_BYTES,
    decode,
    encode,
    pack_array,
    preview,
    unpack_array,
)
from membrane_client.errors import ProtocolError, ServerError, UserError
from membrane_client.live_schema import (
    INITIAL_SHAPES,
    MAX_GRASPS,
    MAX_LOADS,
    MAX_PROBES,
    MAX_TOOLS,
)

__all__ = [
    "ARRAY_DTYPES",
    "MAX_ARRAY_DIMS",
    "MAX_ERROR_CHARS",
    "MAX_GRASPS",
    "MAX_LATTICE_POINTS",
    "MAX_LIVE_POINTS",
    "MAX_LOADS",
    "MAX_NESTING",
    "MAX_PROBES",
    "MAX_REPLY_BYTES",
    "MAX_REQUEST_BYTES",
    "MAX_SESSION_CHARS",
    "MAX_TOKEN_CHARS",
    "MAX_TOOLS",
    "PROTOCOL_VERSION",
    "Domain",
    "ErrorCode",
    "Op",
    "Request",
    "RequestError",
    "StepColumns",
    "check_reply",
    "decode",
    "encode",
    "error_reply",
    "ok_reply",
    "pack_array",
    "peek_reply",
    "preview",
    "read_reply",
    "unpack_array",
]

PROTOCOL_VERSION = 1

# Limits (docs/PROTOCOL.md, "Limits"). Requests are tiny maps; replies carry whole frames
# (MAX_REPLY_BYTES, the codec's). MAX_LOADS and MAX_PROBES per step are live_schema's.
# 128 KiB: an `open` carries a live lattice's initial shapes (2 x 10,000 float32) in one message.
MAX_REQUEST_BYTES = 128 * 1024
MAX_LATTICE_POINTS = 65_536
MAX_SESSION_CHARS = 64
MAX_TOKEN_CHARS = 64  # a live Session's re-send token (``token``)
# Steps one ``step`` request takes (``repeat``): a display's push at 30 frames/s of a 1 kHz
# scene, and no more, so that one request stalls the other sessions at most this many steps.
MAX_REPEAT = 32
# Steps one ``steps`` request takes in all (its items' repeats summed): what one request may hold
# the server for while other peers wait.
MAX_BATCH_STEPS = 256
# An error reply's message: one line of at most this many characters (quoting at most
# codec.PREVIEW_CHARS of any client value).
MAX_ERROR_CHARS = 300
MAX_LIVE_POINTS = 10_000  # a live scene's lattice (100 x 100)


class Op(StrEnum):
    """The operations a version-1 server answers."""

    HELLO = "hello"
    DESCRIBE = "describe"
    QUERY = "query"
    STATS = "stats"
    PING = "ping"
    OPEN = "open"  # the live ops: a session on a live scene (docs/PROTOCOL.md, "Live sessions")
    STEP = "step"
    READ = "read"
    RESET = "reset"
    CLOSE = "close"
    STEPS = "steps"  # several sessions' steps in one request (a client of many environments)
    STEP_COLUMNS = "step_columns"  # many sessions' steps of loads alone, as columns (arrays)


class ErrorCode(StrEnum):
    """The ``code`` of an error reply."""

    BAD_MESSAGE = "bad_message"
    BAD_VERSION = "bad_version"
    BAD_REQUEST = "bad_request"
    UNKNOWN_OP = "unknown_op"
    UNKNOWN_SCENE = "unknown_scene"
    INVALID_TIME = "invalid_time"
    OUT_OF_DOMAIN = "out_of_domain"
    INTERNAL_ERROR = "internal_error"
    NOT_LIVE = "not_live"
    UNKNOWN_SESSION = "unknown_session"
    SESSION_EXISTS = "session_exists"
    STEP_MISMATCH = "step_mismatch"
    TOO_MANY_SESSIONS = "too_many_sessions"


class Domain(StrEnum):
    """Where a query's time fell, as the ``domain`` field of a query reply says."""

    INSIDE = "inside"
    CLAMPED = "clamped"
    HELD = "held"


class RequestError(UserError):
    """A request that breaks the protocol: the server answers it with ``code`` (and the id,
    when it could be read); ``request`` is its envelope (op, id, session) when that was valid."""

    def __init__(self, code: ErrorCode, message: str, request: Request | None = None) -> None:
        super().__init__(message)
        self.code, self.request = code, request
        self.request_id: int | None = None if request is None else request.id


@dataclass(frozen=True, slots=True)
class StepColumns:
    """A ``step_columns`` request's columns, checked for form (each session's step then as a
    ``step`` of loads alone: its k and token, its loads checked by the engine).

    Attributes:
        sessions: the sessions' ids, each at most once.
        k: each session's step index (its step count).
        tokens: each session's token (None where a session has none).
        loads: (sessions, loads, dims + 2) float64: each load's centre, force and radius.
        frames: whether each session's frame is sent.
    """

    sessions: list[str]
    k: list[int]
    tokens: list[str | None]
    loads: Any  # a numpy array (the protocol module imports numpy through the codec only)
    frames: list[bool]

    def to_wire(self) -> dict[str, Any]:
        """The columns as the request's fields (a list of frame flags sent as one when equal)."""
        frames: list[bool] | bool = self.frames
        if len(set(self.frames)) == 1:
            frames = self.frames[0]
        columns: dict[str, Any] = {
            "sessions": self.sessions,
            "k": self.k,
            "loads": pack_array(self.loads, "<f8"),
            "frames": frames,
        }
        if any(token is not None for token in self.tokens):
            columns["tokens"] = self.tokens
        return columns


@dataclass(slots=True)
class Request:
    """One request as the wire carries it (docs/PROTOCOL.md, "Requests"): the client builds
    it and calls ``to_wire``; the server reads it with ``from_wire``."""

    op: str
    id: int
    session: str | None = None
    scene: str | None = None
    t: float | None = None
    dtype: str = "<f4"  # query, step, read: the frame's element type
    k: int | None = None  # step: the index of the step to take (the session's step count)
    # step: live_schema's Load, Probe, Grasp and Tool maps, as sent: their form is checked
    # against the scene's dimension (live_schema.loads_from_wire), once the step is known to apply
    loads: list[Any] | None = None
    probes: list[Any] | None = None
    grasps: list[Any] | None = None
    tools: list[Any] | None = None
    frame: bool = True  # step: whether the reply carries the frame
    # step: refuse an item centred outside the domain (instead of "touches nothing")
    strict: bool = False
    # step: each probe's reading also gives the next step's free displacement (``next_free``)
    lookahead: bool = False
    # step: how many steps to take under the same inputs (the frame and readings: the last's)
    repeat: int = 1
    initial: dict[str, Any] | None = None  # open: {displacement, velocity} arrays
    steps: list[Any] | None = None  # steps: each item a step's map (its own session, k, token)
    columns: StepColumns | None = None  # step_columns: the sessions' steps, column by column
    token: str | None = None  # live ops: the Session object's own token (re-sends carry it)

    def to_wire(self) -> bytes:
        """The request's msgpack bytes; fields left at their defaults are not sent."""
        message: dict[str, Any] = {"v": PROTOCOL_VERSION, "id": self.id, "op": self.op}
        for key in _SENT_FIELDS:
            value = getattr(self, key)
            if value is not None:
                message[key] = value
        if self.dtype != "<f4":
            message["dtype"] = self.dtype
        if not self.frame:
            message["frame"] = False
        if self.strict:
            message["strict"] = True
        if self.lookahead:
            message["lookahead"] = True
        if self.repeat != 1:
            message["repeat"] = self.repeat
        if self.columns is not None:
            message.update(self.columns.to_wire())
        return encode(message)

    @classmethod
    def from_wire(cls, data: bytes) -> Request:
        """Read and check one request; raises RequestError (its ``code`` is the reply's)."""
        try:
            message = decode(data, MAX_REQUEST_BYTES)
        except ProtocolError as exc:
            raise RequestError(ErrorCode.BAD_MESSAGE, str(exc)) from None
        value = message.get("id")
        request_id = value if type(value) is int and 0 <= value < 2**63 else None
        try:
            request = cls._envelope(message, request_id)
        except RequestError as exc:
            exc.request_id = request_id
            raise
        request._read_fields(message)
        return request

    @classmethod
    def _envelope(cls, message: dict[str, Any], request_id: int | None) -> Request:
        if request_id is None:
            reason = f"'id' must be an int in [0, 2^63), got {preview(message.get('id'))}"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        version = message.get("v")
        if type(version) is not int or version != PROTOCOL_VERSION:  # 1.0 and True are not 1
            raise RequestError(
                ErrorCode.BAD_VERSION,
                f"protocol version {preview(version)} unsupported; this server speaks "
                f"version {PROTOCOL_VERSION} (an int)",
            )
        op = message.get("op")
        if not isinstance(op, str):
            raise RequestError(ErrorCode.BAD_REQUEST, f"'op' must be a string, got {preview(op)}")
        if op not in _OPS:
            known = ", ".join(Op)
            raise RequestError(ErrorCode.UNKNOWN_OP, f"unknown op {preview(op)}; ops: {known}")
        session = message.get("session")
        if session is not None and not _is_session_id(session):
            reason = f"'session' must be a string of at most {_SESSION} characters"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        return cls(op, request_id, session)

    @classmethod
    def step_item(cls, item: Any, request_id: int, scene: str | None) -> Request:
        """One item of a ``steps`` request, read as the ``step`` request it stands for (its
        ``scene`` defaults to the batch's); raises RequestError as ``from_wire`` does."""
        if type(item) is not dict:
            raise RequestError(ErrorCode.BAD_REQUEST, f"a steps item is a map, got {preview(item)}")
        session = item.get("session")
        if not _is_session_id(session):
            reason = f"a steps item needs 'session', a string of at most {_SESSION} characters"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        request = cls(Op.STEP, request_id, session)
        request._read_fields({"scene": scene, **item})
        return request

    def _read_fields(self, message: dict[str, Any]) -> None:
        if self.op == Op.STEPS:
            self._read_batch(message)
            return
        if self.op == Op.STEP_COLUMNS:
            self._read_columns(message)
            return
        if self.op not in _SCENE_OPS:  # other ops ignore every other field
            return
        self._read_scene(message)
        if self.op in _LIVE_OPS:
            self._read_live_fields(message)
        if self.op in _FRAME_OPS:
            self._read_dtype(message)
        if self.op != Op.QUERY:
            return
        if "t" not in message:
            self._refuse(ErrorCode.BAD_REQUEST, "query needs 't' (seconds, a float)")
        t = message["t"]
        if isinstance(t, bool) or not isinstance(t, int | float):
            self._refuse(ErrorCode.BAD_REQUEST, f"'t' must be a number, got {preview(t)}")
        self.t = float(t)
        if not math.isfinite(self.t):
            self._refuse(ErrorCode.INVALID_TIME, f"'t' must be finite, got {self.t}")

    def _read_scene(self, message: dict[str, Any]) -> None:
        self.scene = scene = message.get("scene")
        if scene is not None and type(scene) is not str:
            self._refuse(ErrorCode.BAD_REQUEST, f"'scene' must be a string, got {preview(scene)}")

    def _read_live_fields(self, message: dict[str, Any]) -> None:
        if self.session is None:
            self._refuse(ErrorCode.BAD_REQUEST, f"{self.op} needs 'session' (the session's id)")
        token = message.get("token")
        if token is not None and not (type(token) is str and len(token) <= MAX_TOKEN_CHARS):
            reason = f"'token' must be a string of at most {MAX_TOKEN_CHARS} characters"
            self._refuse(ErrorCode.BAD_REQUEST, reason)
        self.token = token
        if self.op == Op.OPEN and (initial := message.get("initial")) is not None:
            if type(initial) is not dict or not initial.keys() <= _INITIAL_SHAPES:
                self._refuse(ErrorCode.BAD_REQUEST, "'initial' must map displacement/velocity")
            self.initial = initial
        if self.op != Op.STEP:
            return
        self.k = k = message.get("k")
        if type(k) is not int or k < 0:
            self._refuse(ErrorCode.BAD_REQUEST, f"step needs 'k' (an int >= 0), got {preview(k)}")
        for key, most in _STEP_ITEMS:
            items = message.get(key, [])
            if type(items) is not list or len(items) > most:
                self._refuse(ErrorCode.BAD_REQUEST, f"'{key}' must be a list of at most {most}")
            setattr(self, key, items)
        self.frame = frame = message.get("frame", True)
        if type(frame) is not bool:
            self._refuse(
                ErrorCode.BAD_REQUEST, f"'frame' must be true or false, got {preview(frame)}"
            )
        self.strict = self._flag(message, "strict")
        self.lookahead = self._flag(message, "lookahead")
        self.repeat = repeat = message.get("repeat", 1)
        if type(repeat) is not int or not 1 <= repeat <= MAX_REPEAT:
            reason = f"'repeat' must be an int in [1, {MAX_REPEAT}], got {preview(repeat)}"
            self._refuse(ErrorCode.BAD_REQUEST, reason)

    def _read_batch(self, message: dict[str, Any]) -> None:
        """``steps``: a list of step maps (each read when it is taken), their repeats within
        ``MAX_BATCH_STEPS`` in all."""
        self._read_scene(message)
        items = message.get("steps")
        if type(items) is not list or not 1 <= len(items) <= MAX_BATCH_STEPS:
            reason = f"'steps' must be a list of 1 to {MAX_BATCH_STEPS} step maps"
            self._refuse(ErrorCode.BAD_REQUEST, reason)
        total = sum(
            item.get("repeat", 1)
            if type(item) is dict and type(item.get("repeat", 1)) is int
            else 1
            for item in items
        )
        if total > MAX_BATCH_STEPS:
            reason = f"a steps request takes at most {MAX_BATCH_STEPS} steps in all, got {total}"
            self._refuse(ErrorCode.BAD_REQUEST, reason)
        self.steps = items

    def _read_columns(self, message: dict[str, Any]) -> None:
        """``step_columns``: equal-length columns of distinct sessions, their k, tokens and
        frame flags, and their loads as one (sessions, loads, dims + 2) array."""
        self._read_scene(message)
        self._read_dtype(message)
        sessions = message.get("sessions")
        if (
            type(sessions) is not list
            or not 1 <= len(sessions) <= MAX_BATCH_STEPS
            or not all(_is_session_id(s) for s in sessions)
        ):
            reason = (
                f"'sessions' must be a list of 1 to {MAX_BATCH_STEPS} session ids (strings of "
                f"at most {_SESSION} characters)"
            )
            self._refuse(ErrorCode.BAD_REQUEST, reason)
        n = len(sessions)
        if len(set(sessions)) != n:
            self._refuse(ErrorCode.BAD_REQUEST, "a session appears at most once in 'sessions'")
        ks = message.get("k")
        if type(ks) is not list or len(ks) != n or not all(type(k) is int and k >= 0 for k in ks):
            self._refuse(ErrorCode.BAD_REQUEST, f"'k' must be a list of {n} ints >= 0")
        tokens = message.get("tokens", [None] * n)
        if (
            type(tokens) is not list
            or len(tokens) != n
            or not all(t is None or (type(t) is str and len(t) <= MAX_TOKEN_CHARS) for t in tokens)
        ):
            reason = f"'tokens' must be a list of {n} tokens (strings, or nil)"
            self._refuse(ErrorCode.BAD_REQUEST, reason)
        frames = message.get("frames", True)
        if type(frames) is bool:
            frames = [frames] * n
        if type(frames) is not list or len(frames) != n or not all(type(f) is bool for f in frames):
            self._refuse(ErrorCode.BAD_REQUEST, f"'frames' must be true, false or {n} of them")
        self.columns = StepColumns(sessions, ks, tokens, self._load_columns(message, n), frames)

    def _load_columns(self, message: dict[str, Any], n: int) -> Any:
        try:
            loads = unpack_array(message.get("loads"), max_dims=3)
        except ProtocolError as exc:
            self._refuse(ErrorCode.BAD_REQUEST, f"'loads': {exc}")
        if loads.ndim != 3 or loads.shape[0] != n or loads.shape[1] > MAX_LOADS:
            got = f"shape {tuple(loads.shape)}" if loads.ndim <= 3 else f"{loads.ndim} axes"
            wanted = f"({n}, loads <= {MAX_LOADS}, dims + 2)"
            reason = f"'loads' must be an array of shape {wanted}, got {got}"
            self._refuse(ErrorCode.BAD_REQUEST, reason)
        return loads.astype("<f8")

    def _read_dtype(self, message: dict[str, Any]) -> None:
        self.dtype = dtype = message.get("dtype", "<f4")
        if dtype not in ARRAY_DTYPES:
            kinds = list(ARRAY_DTYPES)
            self._refuse(
                ErrorCode.BAD_REQUEST, f"'dtype' must be one of {kinds}, got {preview(dtype)}"
            )

    def _flag(self, message: dict[str, Any], key: str) -> bool:
        value = message.get(key, False)
        if type(value) is not bool:
            self._refuse(
                ErrorCode.BAD_REQUEST, f"'{key}' must be true or false, got {preview(value)}"
            )
        return bool(value)

    def _refuse(self, code: ErrorCode, message: str) -> NoReturn:
        raise RequestError(code, message, Request(self.op, self.id, self.session))


_OPS = frozenset(Op)
# The fields ``Request.to_wire`` sends when set, in order; a step's item lists and their bounds.
_SENT_FIELDS = (
    "session", "scene", "t", "k", "loads", "probes", "grasps", "tools", "initial", "token", "steps"
)  # fmt: skip
_STEP_ITEMS = (
    ("loads", MAX_LOADS),
    ("probes", MAX_PROBES),
    ("grasps", MAX_GRASPS),
    ("tools", MAX_TOOLS),
)
_LIVE_OPS = frozenset((Op.OPEN, Op.STEP, Op.READ, Op.RESET, Op.CLOSE))
_SCENE_OPS = frozenset((Op.DESCRIBE, Op.QUERY, *_LIVE_OPS))
_FRAME_OPS = frozenset((Op.QUERY, Op.STEP, Op.READ))  # their replies carry a frame: dtype
_SESSION = MAX_SESSION_CHARS


def _is_session_id(value: Any) -> bool:
    """A session id: a string of at most MAX_SESSION_CHARS characters."""
    return type(value) is str and len(value) <= _SESSION


_INITIAL_SHAPES = frozenset(INITIAL_SHAPES)


def ok_reply(request_id: int | None, **fields: Any) -> dict[str, Any]:
    """Build a success reply to the request with this id."""
    return {"v": PROTOCOL_VERSION, "id": request_id, "ok": True, **fields}


def error_reply(request_id: int | None, code: ErrorCode | str, message: str) -> dict[str, Any]:
    """Build an error reply; ``message`` is flattened to one line of at most
    ``MAX_ERROR_CHARS`` characters."""
    text = " ".join(str(message).split()) or str(code)
    if len(text) > MAX_ERROR_CHARS:
        text = text[: MAX_ERROR_CHARS - 3] + "..."
    return {
        "v": PROTOCOL_VERSION,
        "id": request_id,
        "ok": False,
        "error": {"code": str(code), "message": text},
    }


def check_reply(message: Mapping[str, Any], request_id: int) -> dict[str, Any]:
    """Validate a reply to the request ``request_id`` and return it.

    Raises:
        ServerError: The reply is a well-formed error reply (carries its ``code``).
        ProtocolError: The reply does not follow the protocol or answers another request.
    """
    if message.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(f"reply version {message.get('v')!r}, expected {PROTOCOL_VERSION}")
    ok = message.get("ok")
    if not isinstance(ok, bool):
        raise ProtocolError("reply has no boolean 'ok'")
    if not ok:
        error = message.get("error")
        if not isinstance(error, dict):
            raise ProtocolError("error reply without an 'error' map")
        code, text = error.get("code"), error.get("message")
        if not isinstance(code, str) or not isinstance(text, str):
            raise ProtocolError("error reply needs str 'code' and 'message'")
        # An error to a request the server could not read carries id nil: still ours.
        if message.get("id") not in (request_id, None):
            raise ProtocolError(f"reply id {message.get('id')!r} answers another request")
        raise ServerError(code, text)
    if message.get("id") != request_id:
        raise ProtocolError(f"reply id {message.get('id')!r}, expected {request_id}")
    return dict(message)


def read_reply(data: bytes, request_id: int) -> dict[str, Any]:
    """Decode and check the reply to request ``request_id`` (raises as ``check_reply``)."""
    return check_reply(decode(data), request_id)


def peek_reply(data: bytes) -> tuple[int, str | None]:
    """(request id, None for a success or the error's code) without decoding a frame's arrays.

    For the load tester, which reads only whether each reply answered. Replies begin with their
    envelope (``v``, ``id``, ``ok``); the id is -1 when unreadable, and an undecodable reply's
    code is ``"undecodable"``.
    """
    unpacker = msgpack.Unpacker(raw=False, max_buffer_size=len(data) or 1)
    unpacker.feed(data)
    envelope: dict[Any, Any] = {}
    try:
        remaining = unpacker.read_map_header()
        while remaining and not (envelope.get("ok") is True and "id" in envelope):
            key = unpacker.unpack()
            envelope[key] = unpacker.unpack()
            remaining -= 1
    except Exception:  # msgpack raises a zoo of types on garbage
        return -1, "undecodable"
    request_id = envelope.get("id")
    number = request_id if type(request_id) is int else -1
    if envelope.get("ok") is True:
        return number, None
    error = envelope.get("error")
    code = error.get("code") if isinstance(error, dict) else None
    return number, str(code) if code else "error_without_code"
