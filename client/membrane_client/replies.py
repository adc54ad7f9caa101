"""The ``hello`` and ``stats`` replies (docs/PROTOCOL.md, "Operations"): the server writes them
with ``to_reply_fields``, a client reads them with ``from_reply``, as for ``describe`` and
``query`` (``frame``) and the live ops (``live_schema``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from membrane_client.codec import preview
from membrane_client.errors import ProtocolError

__all__ = ["HelloReply", "ServerLimits", "StatsReply"]

_ENVELOPE = frozenset({"v", "id", "ok"})


class ServerLimits(NamedTuple):
    """``hello``'s ``limits``: what one request, a scene and the session table may hold."""

    max_request_bytes: int
    max_lattice_points: int
    max_sessions: int
    max_sessions_per_peer: int
    session_idle_s: float
    # Per peer, from a server with sockets (None in process): the requests one peer may keep in
    # flight and lose no reply, and the bytes of unread replies kept for it.
    max_in_flight: int | None = None
    peer_budget_bytes: int | None = None

    def to_wire(self) -> dict[str, Any]:
        """The map ``hello`` carries (figures the server does not keep are left out)."""
        return {name: value for name, value in self._asdict().items() if value is not None}


@dataclass(frozen=True)
class HelloReply:
    """Who the server is: its protocol and software versions, its ops, scenes and limits."""

    protocol: int
    server: str  # e.g. "membrane 0.2.0"
    ops: tuple[str, ...]
    scenes: tuple[str, ...]
    default_scene: str | None = None  # the scene a request naming none gets (None: several)
    session: str | None = None  # the request's session id, echoed
    limits: ServerLimits | None = None  # None from a server that sends none
    # `membrane serve --workers N`: every worker's endpoint, this one's included (workers.py);
    # empty from a single server
    workers: tuple[str, ...] = ()

    def to_reply_fields(self) -> dict[str, Any]:
        """The reply's fields (the server writes them)."""
        fields: dict[str, Any] = {
            "protocol": self.protocol,
            "server": self.server,
            "ops": list(self.ops),
            "scenes": list(self.scenes),
            "default_scene": self.default_scene,
            "session": self.session,
        }
        if self.limits is not None:
            fields["limits"] = self.limits.to_wire()
        if self.workers:
            fields["workers"] = list(self.workers)
        return fields

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> HelloReply:
        """Read the reply; raises ProtocolError when a field is missing or malformed."""
        try:
            protocol = reply["protocol"]
            if type(protocol) is not int:
                raise TypeError(f"protocol must be an int, got {preview(protocol)}")
            limits = reply.get("limits")
            return cls(
                protocol=protocol,
                server=str(reply["server"]),
                ops=_names(reply["ops"]),
                scenes=_names(reply["scenes"]),
                default_scene=_optional_name(reply.get("default_scene")),
                session=_optional_name(reply.get("session")),
                limits=None if limits is None else _limits(limits),
                workers=_names(reply.get("workers", [])),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"malformed hello reply: {exc!r}") from None


@dataclass(frozen=True)
class StatsReply:
    """The server's figures since start. A field is None when the server keeps no such figure
    (a dispatcher without counters); ``extra`` holds the figures this version does not name
    (``log``, and whatever a newer server adds), in the order they came."""

    uptime_s: float | None = None
    requests: int | None = None
    errors: dict[str, int] | None = None  # error code -> count
    ops: dict[str, int] | None = None  # op -> count
    scenes: dict[str, int] | None = None  # scene -> queries answered
    sessions: int | None = None  # distinct session ids seen
    latency_us: dict[str, Any] | None = None  # count, window, percentiles, age_s
    dropped_replies: dict[str, int] | None = None  # reason -> count
    failures: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    live: dict[str, Any] | None = None  # the session table's figures

    def to_reply_fields(self) -> dict[str, Any]:
        """The reply's fields: the named figures given, the others, then ``live``."""
        fields = {name: getattr(self, name) for name in _NAMED}
        named = {name: value for name, value in fields.items() if value is not None}
        live = {} if self.live is None else {"live": self.live}
        return {**named, **self.extra, **live}

    @classmethod
    def from_snapshot(
        cls, snapshot: Mapping[str, Any], live: dict[str, Any] | None = None
    ) -> StatsReply:
        """From a counters' snapshot (``membrane_server.stats.Stats.snapshot``'s map)."""
        named = {name: snapshot[name] for name in _NAMED if name in snapshot}
        rest = {k: v for k, v in snapshot.items() if k not in _NAMED_SET and k != "live"}
        return cls(**named, extra=rest, live=live)

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> StatsReply:
        """Read the reply (its envelope left out); raises ProtocolError when a named figure is
        of the wrong type."""
        figures = {k: v for k, v in reply.items() if k not in _ENVELOPE}
        live = figures.get("live")
        if live is not None and not isinstance(live, dict):
            raise ProtocolError(f"malformed stats reply: live is {preview(live)}")
        stats = cls.from_snapshot(figures, live)
        for name, kind in _KINDS.items():
            value = getattr(stats, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, kind)):
                raise ProtocolError(f"malformed stats reply: {name} is {preview(value)}")
        return stats


_NAMED = (
    "uptime_s", "requests", "errors", "ops", "scenes", "sessions", "latency_us",
    "dropped_replies", "failures",
)  # fmt: skip
_NAMED_SET = frozenset(_NAMED)
_KINDS: dict[str, type | tuple[type, ...]] = {
    "uptime_s": (int, float),
    "requests": int,
    "errors": dict,
    "ops": dict,
    "scenes": dict,
    "sessions": int,
    "latency_us": dict,
    "dropped_replies": dict,
    "failures": int,
}


def _names(values: Any) -> tuple[str, ...]:
    if type(values) is not list or not all(type(v) is str for v in values):
        raise TypeError(f"expected a list of names, got {preview(values)}")
    return tuple(values)


def _optional_name(value: Any) -> str | None:
    if value is not None and type(value) is not str:
        raise TypeError(f"expected a name or nil, got {preview(value)}")
    return value


def _limits(value: Any) -> ServerLimits:
    if not isinstance(value, dict):
        raise TypeError(f"limits must be a map, got {preview(value)}")
    return ServerLimits(
        value["max_request_bytes"],
        value["max_lattice_points"],
        value["max_sessions"],
        value["max_sessions_per_peer"],
        value["session_idle_s"],
        value.get("max_in_flight"),
        value.get("peer_budget_bytes"),
    )
