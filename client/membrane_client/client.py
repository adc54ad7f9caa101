"""The thin client: the protocol's operations as methods, over a transport (ZeroMQ REQ with
the zguide's Lazy Pirate by default, see ``transport``)."""

from __future__ import annotations

import itertools
import logging
import time
import uuid
from collections.abc import Mapping
from typing import Any

import zmq

from membrane_client.errors import MembraneError, UserError
from membrane_client.frame import Frame, SceneInfo
from membrane_client.protocol import Op, Request, peek_reply, read_reply
from membrane_client.replies import HelloReply, StatsReply
from membrane_client.session import Session
from membrane_client.transport import LazyPirate, Transport

__all__ = ["DEFAULT_ADDRESS", "Client"]

DEFAULT_ADDRESS = "tcp://127.0.0.1:5555"

logger = logging.getLogger(__name__)


class Client:
    """A connection to a membrane server.

    Not thread-safe: use one Client per thread. Use it as a context manager, or call ``close()``.

    Args:
        address: The server's ZeroMQ endpoint, e.g. ``"tcp://127.0.0.1:5555"``.
        timeout: Seconds to wait for each reply; None waits forever (no Timeout, no retries).
        retries: How many times a request is re-sent on a fresh socket after a timeout.
        scene: The scene requests name by default (needed when the server hosts several).
        session: Session id sent with every request (default: a random 32-hex-digit id; the
            attribute session_id). A live Session (``session()``) sends its own.
        context: ZeroMQ context to use (default: the process-wide shared one).
        socket_options: Extra ``zmq`` socket options set on every socket this client opens
            (e.g. CurveZMQ keys), option -> value.
        transport: Carries the requests instead of ZeroMQ (``transport.Transport``), e.g. to a
            dispatcher in this process; ``address`` then only names it.

    Raises:
        UserError: ``address`` is not a valid ZeroMQ endpoint, or an argument is out of range.
    """

    def __init__(
        self,
        address: str = DEFAULT_ADDRESS,
        timeout: float | None = 1.0,
        retries: int = 0,
        scene: str | None = None,
        *,
        session: str | None = None,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
        socket_options: Mapping[int, int | bytes] | None = None,
        transport: Transport | None = None,
    ) -> None:
        if timeout is not None and not timeout > 0:
            raise UserError(f"timeout must be > 0 seconds (or None), got {timeout}")
        if retries < 0:
            raise UserError(f"retries must be >= 0, got {retries}")
        self.address = address
        self.timeout = timeout
        self.retries = retries if timeout is not None else 0
        self.scene = scene
        self.session_id = session or uuid.uuid4().hex
        self._ids = itertools.count(1)
        self._described: dict[str | None, SceneInfo] = {}
        self._closed = False
        self._transport = transport or LazyPirate(  # fails fast on a malformed address
            address, timeout, self.retries, context, socket_options
        )

    # -- the public operations ---------------------------------------------------------------

    def hello(self) -> HelloReply:
        """The server's protocol version, software version, ops, scenes and limits.

        Raises:
            ProtocolError: a reply that is not a hello reply.
        """
        return HelloReply.from_reply(self.request(Op.HELLO))

    def describe(self, scene: str | None = None, *, refresh: bool = False) -> SceneInfo:
        """The scene's lattice, placement and time grid (cached per scene after the first call)."""
        key = scene or self.scene
        if refresh or key not in self._described:
            info = SceneInfo.from_reply(self.request(Op.DESCRIBE, scene=key))
            self._described[key] = info
        return self._described[key]

    def query(self, t: float, scene: str | None = None, *, dtype: str = "<f4") -> Frame:
        """The frame ``scene`` (default: the client's) serves for simulation time ``t`` (s), its
        displacements as ``dtype``: ``"<f4"`` (float32) or ``"<f8"``.

        The first query of a scene also fetches its description (one extra round trip), so
        that ``Frame.positions()`` works; so does the first query after the server reloaded the
        scene with changes (the reply's revision differs from the description's).
        """
        info = self.describe(scene)
        fields = {"scene": scene or self.scene, "t": float(t), "dtype": dtype}
        reply = self.request(Op.QUERY, **fields)
        if _revision(reply) not in (None, info.revision):
            # The server reloaded this scene with changes: its lattice or placement may differ.
            info = self.describe(scene, refresh=True)
            logger.info("scene %s changed on the server (revision %s): described again",
                        info.name, info.revision)  # fmt: skip
            if _revision(reply) != info.revision:  # reloaded once more in between: ask again
                reply = self.request(Op.QUERY, **fields)
        return Frame.from_reply(reply, info)

    def session(
        self, scene: str | None = None, initial: Mapping[str, Any] | None = None
    ) -> Session:
        """Open a live session on ``scene`` (a context manager; see ``session.Session``), from
        rest or from ``initial`` shapes on the lattice (``{"displacement": ..., "velocity": ...}``).
        """
        return Session(self, scene or self.scene).open(**(initial or {}))

    def stats(self) -> StatsReply:
        """The server's counters and latency percentiles (``request(Op.STATS)`` gives the
        reply's map as it came, which ``membrane stats --json`` prints).

        Raises:
            ProtocolError: a named figure of the wrong type.
        """
        return StatsReply.from_reply(self.request(Op.STATS))

    def ping(self) -> float:
        """One ``ping`` round trip; returns its duration in seconds."""
        start = time.perf_counter()
        self.request(Op.PING)
        return time.perf_counter() - start

    def request(self, op: str, **fields: Any) -> dict[str, Any]:
        """Send one request (``protocol.Request``'s fields) and return its successful reply.

        Fields whose value is None are left out; the session id is added.

        Raises:
            Timeout: No reply within ``timeout`` after ``retries`` re-sends.
            ServerError: The server answered with an error reply (``.code`` says which).
            ProtocolError: The reply was not a valid protocol message.
            MembraneError: The client is closed, or ZeroMQ failed.
        """
        if self._closed:
            raise MembraneError("the client is closed")
        request_id = next(self._ids)
        given = {key: value for key, value in fields.items() if value is not None}
        session = given.pop("session", self.session_id)  # a live Session sends its own id
        payload = Request(op, request_id, session, **given).to_wire()
        reply = self._transport.round_trip(payload, lambda data: _earlier(data, request_id))
        return read_reply(reply, request_id)

    # -- lifecycle ---------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """True once ``close()`` ran."""
        return self._closed

    def close(self) -> None:
        """Close the transport (a socket with LINGER 0: returns at once). Safe to call twice."""
        self._transport.close()
        self._closed = True

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __del__(self) -> None:
        # A forgotten client must not keep a socket that could block the context's term().
        if getattr(self, "_transport", None) is not None:
            self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"Client({self.address!r}, timeout={self.timeout}, scene={self.scene!r}, {state})"


def _revision(reply: dict[str, Any]) -> str | None:
    """A query reply's scene revision (None from servers that send none)."""
    revision = reply.get("revision")
    return revision if isinstance(revision, str) else None


def _earlier(reply: bytes, request_id: int) -> bool:
    """Whether ``reply`` answers an earlier request of this client (a re-send's late twin)."""
    answered = peek_reply(reply)[0]
    return 0 <= answered < request_id
