"""Live sessions on the server: each open session's engine state and last reply, and the table
that bounds them (how many, how long idle).

A session is keyed by the envelope's ``session`` id and bound to the scene (and engine) it
opened on: a reload leaves it on that engine until it closes. With CurveZMQ it is also bound to
its opener's public key: another key is told there is no such session. Without keys a session
id is a bearer token (docs/PROTOCOL.md says so).

A step names the index ``k`` it takes: the session's own count applies it. A re-send (a Lazy
Pirate retry after a lost reply) is recognised by the ``Session`` object's own random
``token``, the op and k (and the scene, for ``open``), never by the request id alone: two
clients number their requests alike. Anything else is refused with the session's k.

Fairness: each peer (a connection without CurveZMQ, a key with it) holds at most
``max_per_peer`` sessions, within the global ``max_sessions``.

Every wire form is the client's live schema's (``membrane_client.live_schema``): a step's load
and probe maps are read through it into the engine's own ``Load`` and ``Probe`` (the schema
checks their form, the engine their values), and every reply is one of its reply forms.
"""

from __future__ import annotations

import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from membrane_client import live_schema as schema
from membrane_client.live_schema import (
    MAX_LOADS,
    MAX_PROBES,
    STEP_UNITS,
    CloseReply,
    Initial,
    LiveInputError,
    LiveStepReply,
    OpenReply,
    ResetReply,
)
from membrane_client.protocol import (
    ErrorCode,
    Request,
    RequestError,
    decode,
    encode,
    ok_reply,
    preview,
)
from membrane_models.live import (
    LiveEngine,
    LiveError,
    Load,
    Probe,
    ProbeReading,
    Start,
    StepResult,
)
from membrane_models.problems import Problem
from membrane_server.engines import build_engine

if TYPE_CHECKING:
    from membrane_server.dispatch import ServedScene
    from membrane_server.scene import Scene

__all__ = [
    "DEFAULT_IDLE_S",
    "DEFAULT_MAX_PER_PEER",
    "DEFAULT_MAX_SESSIONS",
    "LiveOps",
    "LiveSession",
    "SessionTable",
    "build_scene_engine",
    "engine_inputs",
    "input_error",
    "live_description",
    "wire_error",
]

DEFAULT_MAX_SESSIONS = 64
DEFAULT_MAX_PER_PEER = 16
DEFAULT_IDLE_S = 300.0
# Python objects around a session (its record, the table's entry, stored replies' headers).
_SESSION_OVERHEAD = 4096
# A live reply beside its frame: the envelope and up to MAX_PROBES readings.
_REPLY_OVERHEAD = 512 + MAX_PROBES * 160


def build_scene_engine(scene: Scene, problem: Problem) -> LiveEngine[Any]:
    """The live engine of a scene with a ``[live]`` table, by its kind, on its lattice and dt."""
    assert scene.live is not None
    settings = scene.live
    return build_engine(settings.engine, problem, scene.lattice.shape, scene.dt, settings.options)


def live_description(engine: LiveEngine[Any]) -> dict[str, Any]:
    """``describe``'s ``live`` field: the engine's settings and bounds (its own ``describe``),
    the per-step limits, the memory a session holds at most, and the units of a step."""
    return {
        **engine.describe(),
        "max_loads": MAX_LOADS,
        "max_probes": MAX_PROBES,
        "session_bytes": session_bytes(engine),
        "units": STEP_UNITS,
    }


def session_bytes(engine: LiveEngine[Any]) -> int:
    """The most one session holds: its start and current states (each at most the engine's
    ``state_bytes``), its stored open and step replies."""
    frame = 4 * math.prod(engine.lattice_shape)
    return 2 * engine.state_bytes + 2 * _REPLY_OVERHEAD + frame + _SESSION_OVERHEAD


def _reading(engine_reading: ProbeReading) -> schema.ProbeReading:
    """An engine's probe reading in the schema's form (its wire map is ``to_wire()``)."""
    r = engine_reading
    return schema.ProbeReading(r.force, r.displacement, r.gap, r.in_contact, r.outside)


def engine_inputs(request: Request, dims: int) -> tuple[tuple[Load, ...], tuple[Probe, ...]]:
    """A step's wire loads and probes, read through the client's live schema (their maps'
    form), as the engine's own types (whose values the engine checks)."""
    try:
        loads = schema.loads_from_wire(request.loads or (), dims)
        probes = schema.probes_from_wire(request.probes or (), dims)
    except LiveInputError as exc:
        raise input_error(exc) from None
    return (
        tuple([Load(*load) for load in loads]),
        tuple([Probe(*probe) for probe in probes]),
    )


class Sent(NamedTuple):
    """What identifies a request among re-sends, and the reply it got."""

    token: str | None
    request_id: int
    reply: bytes

    def reply_to(self, request: Request) -> bytes:
        """The stored reply, for a re-send: byte for byte when it carries the same request id
        (a Lazy Pirate retry), else under the re-send's own id (a retry that was numbered
        anew), so that its client accepts it."""
        if request.id == self.request_id:
            return self.reply
        return encode({**decode(self.reply), "id": request.id})

    def resent_by(self, request: Request) -> bool:
        """Whether ``request`` re-sends this one: the same Session token (and, without a token,
        the same request id: all a client without tokens can be told apart by)."""
        if request.token is not None or self.token is not None:
            return request.token == self.token
        return request.id == self.request_id


@dataclass
class LiveSession:
    """One open session: the scene it opened on, its owner, its start, its state and its last
    replies."""

    served: ServedScene
    start: Start[Any]
    state: Any  # the engine's own state type (immutable)
    opened: Sent  # the open (a re-sent open gets its reply again)
    owner: str = ""  # the peer that opened it ("key:..." binds it to that CurveZMQ key)
    k: int = 0  # steps taken (counted here: an engine's state type is its own)
    last_step: Sent | None = None  # the latest step
    readings: tuple[ProbeReading, ...] = ()
    last_used: float = field(default=0.0)

    @property
    def t(self) -> float:
        """The session's time, k dt."""
        return self.k * self.engine.dt

    @property
    def engine(self) -> LiveEngine[Any]:
        engine = self.served.live
        assert engine is not None  # a session opens on live scenes only
        return engine

    def visible_to(self, peer: str) -> bool:
        """A key-bound session is its key's alone; without keys the id is the credential."""
        return not self.owner.startswith("key:") or peer == self.owner

    def apply(self, result: StepResult[Any]) -> None:
        self.state, self.readings, self.k = result.state, result.probes, self.k + 1

    def reset(self) -> None:
        self.state, self.readings, self.last_step, self.k = self.start.state, (), None, 0


class SessionTable:
    """The open sessions: at most ``max_sessions`` in all and ``max_per_peer`` per peer, each
    expiring after ``idle_s`` unused.

    Kept by the server across reloads (each Dispatcher gets the same table).
    """

    def __init__(
        self,
        max_sessions: int = DEFAULT_MAX_SESSIONS,
        idle_s: float = DEFAULT_IDLE_S,
        clock: Callable[[], float] = time.monotonic,
        max_per_peer: int = DEFAULT_MAX_PER_PEER,
    ) -> None:
        if max_sessions < 1 or max_per_peer < 1 or not idle_s > 0:
            raise ValueError("max_sessions and max_per_peer must be >= 1 and idle_s > 0")
        self.max_sessions, self.idle_s, self._clock = max_sessions, idle_s, clock
        self.max_per_peer = max_per_peer
        self._sessions: OrderedDict[str, LiveSession] = OrderedDict()  # least recently used first
        self._per_peer: Counter[str] = Counter()
        self.counts: Counter[str] = Counter()

    def __len__(self) -> int:
        return len(self._sessions)

    def get(self, session_id: str, peer: str = "") -> LiveSession | None:
        """The open session with this id that ``peer`` may use (None if none, or expired),
        marked used now."""
        self._expire()
        session = self._sessions.get(session_id)
        if session is None or not session.visible_to(peer):
            return None
        session.last_used = self._clock()
        self._sessions.move_to_end(session_id)
        return session

    def require(self, session_id: str, peer: str = "") -> LiveSession:
        """``get``, or the ``unknown_session`` refusal."""
        session = self.get(session_id, peer)
        if session is None:
            raise RequestError(
                ErrorCode.UNKNOWN_SESSION,
                f"no open session {preview(session_id)} (never opened, closed, opened with "
                f"another key, or idle for more than {self.idle_s:g} s): open one",
            )
        return session

    def taken(self, session_id: str) -> bool:
        """Whether any session, visible to the asker or not, has this id."""
        self._expire()
        return session_id in self._sessions

    def add(self, session_id: str, session: LiveSession) -> None:
        """Register a new session (raises ``too_many_sessions`` when the table or the peer's
        share of it is full)."""
        self._expire()
        if len(self._sessions) >= self.max_sessions:
            self.counts["refused"] += 1
            raise RequestError(
                ErrorCode.TOO_MANY_SESSIONS,
                f"{len(self._sessions)} live sessions are open, the limit: close one, or wait "
                f"for an idle one to expire ({self.idle_s:g} s)",
            )
        if self._per_peer[session.owner] >= self.max_per_peer:
            self.counts["refused"] += 1
            raise RequestError(
                ErrorCode.TOO_MANY_SESSIONS,
                f"this peer holds {self.max_per_peer} live sessions, the most one peer may "
                "(a connection, or a CurveZMQ key): close one",
            )
        session.last_used = self._clock()
        self._sessions[session_id] = session
        self._per_peer[session.owner] += 1
        self.counts["opened"] += 1

    def close(self, session_id: str, peer: str = "") -> bool:
        """Forget a session ``peer`` may use; True when it was open."""
        session = self._sessions.get(session_id)
        if session is None or not session.visible_to(peer):
            return False
        self._remove(session_id)
        self.counts["closed"] += 1
        return True

    def close_revision(self, revision: str) -> int:
        """Close every session opened on a scene of this revision (a reload's old scenes past
        the bound on revisions held); returns how many."""
        doomed = [sid for sid, s in self._sessions.items() if s.served.revision == revision]
        for session_id in doomed:
            self._remove(session_id)
        self.counts["closed"] += len(doomed)
        return len(doomed)

    def revisions(self) -> set[str]:
        """The scene revisions the open sessions hold."""
        return {session.served.revision for session in self._sessions.values()}

    def snapshot(self) -> dict[str, Any]:
        """The ``stats`` reply's ``live`` figures."""
        self._expire()
        return {
            "open": len(self._sessions),
            "max_sessions": self.max_sessions,
            "max_per_peer": self.max_per_peer,
            "idle_s": self.idle_s,
            **{name: self.counts[name] for name in _COUNTS},
        }

    def _remove(self, session_id: str) -> None:
        session = self._sessions.pop(session_id)
        self._per_peer[session.owner] -= 1
        if self._per_peer[session.owner] <= 0:
            del self._per_peer[session.owner]

    def _expire(self) -> None:
        deadline = self._clock() - self.idle_s
        while self._sessions:
            session_id, oldest = next(iter(self._sessions.items()))
            if oldest.last_used > deadline:
                return
            self._remove(session_id)
            self.counts["expired"] += 1


_COUNTS = ("opened", "closed", "expired", "refused", "steps", "resent", "mismatches")


class LiveOps:
    """The live ops (open, step, read, reset, close), each returning its whole reply's bytes
    (so that a re-sent open or step can get exactly the same bytes again).

    Args:
        table: The open sessions.
        scene_of: The served scene a request names (the dispatcher's rule, raising its
            refusals); a plain function, so that nothing here refers back to a dispatcher.
    """

    def __init__(self, table: SessionTable, scene_of: Callable[[Request], ServedScene]) -> None:
        self.table, self._scene_of = table, scene_of

    def open(self, request: Request, peer: str = "") -> bytes:
        session_id = _session_id(request)
        served = self._scene_of(request)
        if served.live is None:
            raise RequestError(ErrorCode.NOT_LIVE, f"scene {served.name} is a film, not live")
        existing = self.table.get(session_id, peer)
        if existing is not None:
            same_scene = existing.served.name == served.name
            if same_scene and existing.opened.resent_by(request):  # a re-sent open
                return existing.opened.reply_to(request)
            raise RequestError(ErrorCode.SESSION_EXISTS, "this session id is open: close it first")
        if self.table.taken(session_id):  # another key's: say no more than that it is taken
            raise RequestError(ErrorCode.SESSION_EXISTS, "this session id is taken: pick another")
        start = _start(served.live, request.initial)
        fields = OpenReply(
            session=session_id,
            revision=served.revision,
            displacement_residual=start.displacement_residual,
            velocity_residual=start.velocity_residual,
        ).to_reply_fields()
        reply = encode(ok_reply(request.id, **fields))
        opened = Sent(request.token, request.id, reply)
        self.table.add(session_id, LiveSession(served, start, start.state, opened, peer))
        return reply

    def step(self, request: Request, peer: str = "") -> bytes:
        session = self._session(request, peer)
        k = request.k
        if k != session.k:
            last = session.last_step
            if k == session.k - 1 and last is not None and last.resent_by(request):
                self.table.counts["resent"] += 1
                return last.reply_to(request)  # a re-send: never applied twice
            self.table.counts["mismatches"] += 1
            raise RequestError(
                ErrorCode.STEP_MISMATCH,
                f"the session has taken {session.k} steps: the next step is k = {session.k}, "
                f"this one asked for k = {preview(k)}",
            )
        engine = session.engine
        _require_inputs(engine, loads=request.loads, probes=request.probes)
        loads, probes = engine_inputs(request, engine.spatial_dims)
        try:
            result = engine.step(session.state, loads, probes, frame=request.frame)
        except LiveError as exc:
            raise wire_error(exc) from None
        session.apply(result)
        self.table.counts["steps"] += 1
        fields = self._state_reply(request, session, result.frame).to_reply_fields()
        reply = encode(ok_reply(request.id, **fields))
        session.last_step = Sent(request.token, request.id, reply)
        return reply

    def read(self, request: Request, peer: str = "") -> bytes:
        session = self._session(request, peer)
        frame = session.engine.frame(session.state)
        last = session.last_step  # whose step this state follows
        token = None if last is None else last.token
        fields = self._state_reply(request, session, frame, token).to_reply_fields()
        return encode(ok_reply(request.id, **fields))

    def reset(self, request: Request, peer: str = "") -> bytes:
        session = self._session(request, peer)
        session.reset()
        fields = ResetReply(_session_id(request)).to_reply_fields()
        return encode(ok_reply(request.id, **fields))

    def close(self, request: Request, peer: str = "") -> bytes:
        session_id = _session_id(request)
        closed = self.table.close(session_id, peer)
        return encode(ok_reply(request.id, **CloseReply(session_id, closed).to_reply_fields()))

    def _session(self, request: Request, peer: str) -> LiveSession:
        session = self.table.require(_session_id(request), peer)
        if request.scene is not None and request.scene != session.served.name:
            reason = f"this session is on scene {session.served.name}, not {preview(request.scene)}"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        return session

    @staticmethod
    def _state_reply(
        request: Request,
        session: LiveSession,
        frame: np.ndarray | None,
        token: str | None = None,
    ) -> LiveStepReply:
        return LiveStepReply(
            session=_session_id(request),
            k=session.k,
            t=session.t,
            revision=session.served.revision,
            probes=tuple([_reading(r) for r in session.readings]),
            z=None if frame is None else np.reshape(frame, session.served.shape),
            token=token,
        )


def _session_id(request: Request) -> str:
    assert request.session is not None  # Request.from_wire requires it of the live ops
    return request.session


def wire_error(exc: LiveError, what: str = "") -> RequestError:
    """The one place an engine's refusal becomes a wire error: ``bad_request`` with the
    engine's message (its errors quote client values bounded; ``error_reply`` caps the length)."""
    return RequestError(ErrorCode.BAD_REQUEST, f"{what}{exc}")


def input_error(exc: LiveInputError) -> RequestError:
    """The live schema's refusal of a wire item as a wire error: ``bad_request`` with its
    message (which quotes client values bounded)."""
    return RequestError(ErrorCode.BAD_REQUEST, str(exc))


def _require_inputs(engine: LiveEngine[Any], **given: object) -> None:
    """Refuse what the engine does not take (``LiveEngine.inputs``) before it reaches it."""
    for name, value in given.items():
        if value and name not in engine.inputs:
            takes = ", ".join(sorted(engine.inputs)) or "nothing"
            raise RequestError(
                ErrorCode.BAD_REQUEST, f"this scene's engine takes no {name} (it takes {takes})"
            )


def _start(engine: LiveEngine[Any], initial: dict[str, Any] | None) -> Start[Any]:
    _require_inputs(engine, initial=initial)
    try:
        shapes = Initial.from_wire(initial)
    except LiveInputError as exc:
        raise input_error(exc) from None
    try:
        return engine.start(shapes.displacement, shapes.velocity)
    except LiveError as exc:
        raise wire_error(exc, "initial: ") from None
