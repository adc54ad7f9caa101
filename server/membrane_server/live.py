"""Live sessions on the server: each open session's engine state and last reply, and the table
that bounds them (how many, how long idle).

A session is keyed by the envelope's ``session`` id and bound to the scene (and engine) it
opened on: a reload leaves it on that engine until it closes. A step names the index ``k`` it
takes: the session's own count applies it; the previous index with the same request id is a
Lazy Pirate re-send and gets the stored reply; anything else is refused with the session's k.
The ops themselves are the dispatcher's (``dispatch.Dispatcher``); this module holds the state.
"""

from __future__ import annotations

import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from membrane_client.errors import ProtocolError
from membrane_client.protocol import (
    MAX_LOADS,
    MAX_PROBES,
    ErrorCode,
    Request,
    RequestError,
    encode,
    ok_reply,
    pack_array,
    preview,
    unpack_array,
)
from membrane_models.live import (
    LiveError,
    ModalEngine,
    ModalState,
    ProbeReading,
    Start,
    StepResult,
)

if TYPE_CHECKING:
    from membrane_server.dispatch import ServedScene
    from membrane_server.scene import Scene

__all__ = [
    "DEFAULT_IDLE_S",
    "DEFAULT_MAX_SESSIONS",
    "LiveOps",
    "LiveSession",
    "SessionTable",
    "build_engine",
    "live_description",
    "reading_fields",
]

DEFAULT_MAX_SESSIONS = 64
DEFAULT_IDLE_S = 300.0


def build_engine(scene: Scene, problem: Any) -> ModalEngine:
    """The live engine of a scene with a ``[live]`` table, on the scene's lattice and dt."""
    assert scene.live is not None
    settings = scene.live
    return ModalEngine(
        problem,
        scene.lattice.shape,
        scene.dt,
        damping=settings.damping,
        hold=settings.hold,
        modes=settings.modes,
    )


def live_description(engine: ModalEngine) -> dict[str, Any]:
    """``describe``'s ``live`` field: the engine's settings, the per-step limits, the memory a
    session holds, and the units of what a step carries."""
    modes = math.prod(engine.modes.box)
    frame = math.prod(engine.lattice_shape)
    return {
        **engine.describe(),
        "max_loads": MAX_LOADS,
        "max_probes": MAX_PROBES,
        # q, v and the held load force per mode, the initial state, and the last reply's frame.
        "session_bytes": 5 * modes * 8 + frame * 4 + 4096,
        "units": {
            "at": "problem units (lattice coordinates)",
            "force": "total force, problem units; a load's > 0 pushes along +axis",
            "depth": "below the rest surface, problem units (a probe presses along -axis)",
            "k": "steps taken; t = k * dt",
        },
    }


def reading_fields(reading: ProbeReading) -> dict[str, Any]:
    """A probe's reading as the wire carries it."""
    return {
        "force": reading.force,
        "displacement": reading.displacement,
        "gap": reading.gap,
        "in_contact": reading.in_contact,
        "outside": reading.outside,
    }


@dataclass
class LiveSession:
    """One open session: the scene it opened on, its start, its state and its last replies."""

    served: ServedScene
    start: Start[ModalState]
    state: ModalState
    opened: tuple[int, bytes]  # the open's request id and reply (a re-sent open gets it again)
    last_step: tuple[int, bytes] | None = None  # the latest step's request id and reply
    readings: tuple[ProbeReading, ...] = ()
    last_used: float = field(default=0.0)

    @property
    def k(self) -> int:
        """Steps taken."""
        return self.state.step

    @property
    def engine(self) -> ModalEngine:
        engine = self.served.live
        assert engine is not None  # a session opens on live scenes only
        return engine

    def apply(self, result: StepResult[ModalState]) -> None:
        self.state, self.readings = result.state, result.probes

    def reset(self) -> None:
        self.state, self.readings, self.last_step = self.start.state, (), None


class SessionTable:
    """The open sessions: at most ``max_sessions``, each expiring after ``idle_s`` unused.

    Kept by the server across reloads (each Dispatcher gets the same table).
    """

    def __init__(
        self,
        max_sessions: int = DEFAULT_MAX_SESSIONS,
        idle_s: float = DEFAULT_IDLE_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if max_sessions < 1 or not idle_s > 0:
            raise ValueError("max_sessions must be >= 1 and idle_s > 0")
        self.max_sessions, self.idle_s, self._clock = max_sessions, idle_s, clock
        self._sessions: OrderedDict[str, LiveSession] = OrderedDict()  # least recently used first
        self.counts: Counter[str] = Counter()

    def __len__(self) -> int:
        return len(self._sessions)

    def get(self, session_id: str) -> LiveSession | None:
        """The open session with this id (None if none, or expired), marked used now."""
        self._expire()
        session = self._sessions.get(session_id)
        if session is not None:
            session.last_used = self._clock()
            self._sessions.move_to_end(session_id)
        return session

    def require(self, session_id: str) -> LiveSession:
        """``get``, or the ``unknown_session`` refusal."""
        session = self.get(session_id)
        if session is None:
            raise RequestError(
                ErrorCode.UNKNOWN_SESSION,
                f"no open session {session_id[:64]!r} (never opened, closed, or idle for more "
                f"than {self.idle_s:g} s): open one",
            )
        return session

    def add(self, session_id: str, session: LiveSession) -> None:
        """Register a new session (raises ``too_many_sessions`` when full)."""
        self._expire()
        if len(self._sessions) >= self.max_sessions:
            self.counts["refused"] += 1
            raise RequestError(
                ErrorCode.TOO_MANY_SESSIONS,
                f"{len(self._sessions)} live sessions are open, the limit: close one, or wait "
                f"for an idle one to expire ({self.idle_s:g} s)",
            )
        session.last_used = self._clock()
        self._sessions[session_id] = session
        self.counts["opened"] += 1

    def close(self, session_id: str) -> bool:
        """Forget a session; True when it was open."""
        closed = self._sessions.pop(session_id, None) is not None
        self.counts["closed"] += closed
        return closed

    def snapshot(self) -> dict[str, Any]:
        """The ``stats`` reply's ``live`` figures."""
        self._expire()
        return {
            "open": len(self._sessions),
            "max_sessions": self.max_sessions,
            "idle_s": self.idle_s,
            **{name: self.counts[name] for name in _COUNTS},
        }

    def _expire(self) -> None:
        deadline = self._clock() - self.idle_s
        while self._sessions:
            oldest = next(iter(self._sessions.values()))
            if oldest.last_used > deadline:
                return
            self._sessions.popitem(last=False)
            self.counts["expired"] += 1


_COUNTS = ("opened", "closed", "expired", "refused", "steps", "resent", "mismatches")


class LiveOps:
    """The live ops (open, step, read, reset, close), each returning its whole reply's bytes
    (so that a re-sent open or step can get exactly the same bytes again).

    Args:
        table: The open sessions.
        scene_of: The served scene a request names (the dispatcher's rule, raising its refusals).
    """

    def __init__(self, table: SessionTable, scene_of: Callable[[Request], ServedScene]) -> None:
        self.table, self._scene_of = table, scene_of

    def open(self, request: Request) -> bytes:
        session_id = _session_id(request)
        served = self._scene_of(request)
        if served.live is None:
            raise RequestError(ErrorCode.NOT_LIVE, f"scene {served.name} is a film, not live")
        existing = self.table.get(session_id)
        if existing is not None:
            if existing.opened[0] == request.id:  # a re-sent open: the same reply
                return existing.opened[1]
            raise RequestError(ErrorCode.SESSION_EXISTS, "this session id is open: close it first")
        start = _start(served.live, request.initial)
        fields = {
            "session": session_id,
            "k": 0,
            "t": 0.0,
            "revision": served.revision,
            "residuals": {
                "displacement": start.displacement_residual,
                "velocity": start.velocity_residual,
            },
        }
        reply = encode(ok_reply(request.id, **fields))
        self.table.add(session_id, LiveSession(served, start, start.state, (request.id, reply)))
        return reply

    def step(self, request: Request) -> bytes:
        session = self._session(request)
        k = request.k
        if k != session.k:
            if k == session.k - 1 and session.last_step and session.last_step[0] == request.id:
                self.table.counts["resent"] += 1
                return session.last_step[1]  # a Lazy Pirate re-send: never applied twice
            self.table.counts["mismatches"] += 1
            raise RequestError(
                ErrorCode.STEP_MISMATCH,
                f"the session has taken {session.k} steps: the next step is k = {session.k}, "
                f"this one asked for k = {k}",
            )
        try:
            result = session.engine.step(
                session.state, request.loads or (), request.probes or (), frame=request.frame
            )
        except LiveError as exc:
            raise RequestError(ErrorCode.BAD_REQUEST, str(exc)) from None
        session.apply(result)
        self.table.counts["steps"] += 1
        fields = self._frame_fields(request, session, result.frame)
        reply = encode(ok_reply(request.id, **fields))
        session.last_step = (request.id, reply)
        return reply

    def read(self, request: Request) -> bytes:
        session = self._session(request)
        frame = session.engine.frame(session.state)
        return encode(ok_reply(request.id, **self._frame_fields(request, session, frame)))

    def reset(self, request: Request) -> bytes:
        session = self._session(request)
        session.reset()
        return encode(ok_reply(request.id, session=request.session, k=0, t=0.0))

    def close(self, request: Request) -> bytes:
        closed = self.table.close(_session_id(request))
        return encode(ok_reply(request.id, session=request.session, closed=closed))

    def _session(self, request: Request) -> LiveSession:
        session = self.table.require(_session_id(request))
        if request.scene is not None and request.scene != session.served.name:
            reason = f"this session is on scene {session.served.name}, not {preview(request.scene)}"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        return session

    @staticmethod
    def _frame_fields(
        request: Request, session: LiveSession, frame: np.ndarray | None
    ) -> dict[str, Any]:
        state = session.state
        fields: dict[str, Any] = {
            "session": request.session,
            "k": state.step,
            "t": state.time,
            "revision": session.served.revision,
            "probes": [reading_fields(reading) for reading in session.readings],
        }
        if frame is not None:
            fields["z"] = pack_array(np.reshape(frame, session.served.shape), "<f4")
        return fields


def _session_id(request: Request) -> str:
    assert request.session is not None  # Request.from_wire requires it of the live ops
    return request.session


def _start(engine: ModalEngine, initial: dict[str, Any] | None) -> Start[ModalState]:
    shapes = {}
    for name, packed in (initial or {}).items():
        try:
            shapes[name] = unpack_array(packed).reshape(-1)
        except ProtocolError as exc:
            raise RequestError(ErrorCode.BAD_REQUEST, f"initial {name}: {exc}") from None
    try:
        return engine.start(shapes.get("displacement"), shapes.get("velocity"))
    except LiveError as exc:
        raise RequestError(ErrorCode.BAD_REQUEST, f"initial: {exc}") from None
