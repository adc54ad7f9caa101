"""Live sessions on the server: each open session's engine state and last replies, and the table
that bounds them (how many in all and per peer, how long idle, whose they are).

A session is keyed by the envelope's ``session`` id and bound to the scene (and engine) it
opened on: a reload leaves it on that engine until it closes. With CurveZMQ it is also bound to
its opener's public key: another key is told there is no such session. Without keys a session
id is a bearer token (docs/PROTOCOL.md says so). A re-send is told by the ``Session`` object's
own random ``token`` (``same_sender``), never by the request id alone. Each peer (a
connection without CurveZMQ, a key with it) holds at most ``max_per_peer`` sessions, within
the global ``max_sessions``. The ops on them are ``live.LiveOps``'.
"""

from __future__ import annotations

import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

from membrane_client.protocol import (
    ErrorCode,
    Request,
    RequestError,
    decode,
    encode,
    preview,
)
from membrane_models.live import (
    GraspReading,
    LiveEngine,
    ProbeReading,
    Start,
    StepResult,
    ToolReading,
)

if TYPE_CHECKING:
    from membrane_server.served import ServedScene


__all__ = [
    "DEFAULT_IDLE_S",
    "DEFAULT_MAX_PER_PEER",
    "DEFAULT_MAX_SESSIONS",
    "LiveSession",
    "Sent",
    "SessionTable",
    "StoredStep",
    "same_sender",
]

DEFAULT_MAX_SESSIONS = 64
DEFAULT_MAX_PER_PEER = 16
DEFAULT_IDLE_S = 300.0


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
        """Whether ``request`` re-sends this one (``same_sender``)."""
        return same_sender(self.token, self.request_id, request.token, request.id)


def same_sender(token: str | None, request_id: int, again: str | None, again_id: int) -> bool:
    """Whether a request (token ``again``, id ``again_id``) re-sends the one stored: the same
    Session token (and, without a token, the same request id: all a client without tokens can
    be told apart by)."""
    if again is not None or token is not None:
        return again == token
    return again_id == request_id


class StoredStep(Protocol):
    """A session's latest step as kept for a re-send: a lone step's reply (``Sent``), or a step
    of a ``step_columns`` request kept as its values (``step_columns.ColumnStep``)."""

    @property
    def token(self) -> str | None: ...

    @property
    def request_id(self) -> int: ...

    def reply_to(self, request: Request) -> bytes: ...


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
    last_step: StoredStep | None = None  # the latest step
    last_k: int = -1  # the ``k`` the latest step asked for (a re-send asks it again)
    readings: tuple[ProbeReading, ...] = ()
    grasp_readings: tuple[GraspReading, ...] = ()
    tool_readings: tuple[ToolReading, ...] = ()
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

    def apply(self, result: StepResult[Any], steps: int = 1) -> None:
        """The state after ``steps`` steps (one request's), and its last step's readings."""
        self.last_k = self.k
        self.state, self.readings, self.k = result.state, result.probes, self.k + steps
        self.grasp_readings, self.tool_readings = result.grasps, result.tools

    def reset(self) -> None:
        self.state, self.readings, self.last_step, self.k = self.start.state, (), None, 0
        self.last_k = -1
        self.grasp_readings, self.tool_readings = (), ()


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

    def resent_step(
        self, session: LiveSession, k: int, token: str | None, request_id: int
    ) -> StoredStep:
        """The stored step that a step asking for ``k`` (not the session's next) re-sends, or
        the ``step_mismatch`` refusal; each counted (``resent``, ``mismatches``)."""
        last = session.last_step
        if (
            k == session.last_k
            and last is not None
            and same_sender(last.token, last.request_id, token, request_id)
        ):
            self.counts["resent"] += 1
            return last
        self.counts["mismatches"] += 1
        raise RequestError(
            ErrorCode.STEP_MISMATCH,
            f"the session has taken {session.k} steps: the next step is k = {session.k}, "
            f"this one asked for k = {preview(k)}",
        )

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
