"""The thin client: REQ semantics over ZeroMQ, with the zguide's Lazy Pirate on timeouts.

After a timeout the REQ socket is in a state where it can neither send nor receive; it is closed
(LINGER 0) and a fresh one is opened for the next attempt, never reused. Every socket has LINGER 0,
so closing a client (or exiting the interpreter) never waits on undelivered messages.
"""

from __future__ import annotations

import itertools
import logging
import time
import uuid
from collections.abc import Mapping
from types import TracebackType
from typing import Any

import zmq

from membrane_client.errors import MembraneError, Timeout, UserError
from membrane_client.frame import Frame, SceneInfo
from membrane_client.protocol import (
    MAX_REPLY_BYTES,
    Op,
    check_reply,
    decode,
    encode,
    request,
)

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
        session: Session id sent with every request (default: a random 32-hex-digit id).
        context: ZeroMQ context to use (default: the process-wide shared one).
        socket_options: Extra ``zmq`` socket options set on every socket this client opens
            (e.g. CurveZMQ keys), option -> value.

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
    ) -> None:
        if timeout is not None and not timeout > 0:
            raise UserError(f"timeout must be > 0 seconds (or None), got {timeout}")
        if retries < 0:
            raise UserError(f"retries must be >= 0, got {retries}")
        self.address = address
        self.timeout = timeout
        self.retries = retries if timeout is not None else 0
        self.scene = scene
        self.session = session or uuid.uuid4().hex
        self._context = context or zmq.Context.instance()
        self._socket_options = dict(socket_options or {})
        self._ids = itertools.count(1)
        self._described: dict[str | None, SceneInfo] = {}
        self._socket: zmq.Socket[bytes] | None = None
        self._closed = False
        self._socket = self._open_socket()  # fails fast on a malformed address

    # -- the public operations ---------------------------------------------------------------

    def hello(self) -> dict[str, Any]:
        """The server's protocol version, software version, ops, scenes and limits."""
        return self.request(Op.HELLO)

    def describe(self, scene: str | None = None, *, refresh: bool = False) -> SceneInfo:
        """The scene's lattice, placement and time grid (cached per scene after the first call)."""
        key = scene or self.scene
        if refresh or key not in self._described:
            info = SceneInfo.from_reply(self.request(Op.DESCRIBE, scene=key))
            self._described[key] = info
        return self._described[key]

    def query(self, t: float, scene: str | None = None, *, dtype: str = "<f4") -> Frame:
        """The frame the scene serves for simulation time ``t`` (seconds).

        The first query of a scene also fetches its description (one extra round trip), so
        that ``Frame.positions()`` works; so does the first query after the server reloaded the
        scene with changes (the reply's revision differs from the description's).

        Args:
            t: Simulation time, seconds.
            scene: Scene name (default: the client's ``scene``).
            dtype: ``"<f4"`` (float32, the default) or ``"<f8"`` for float64 displacements.
        """
        info = self.describe(scene)
        wire_dtype = None if dtype == "<f4" else dtype  # the default needs no field
        fields = {"scene": scene or self.scene, "t": float(t), "dtype": wire_dtype}
        reply = self.request(Op.QUERY, **fields)
        if _revision(reply) not in (None, info.revision):
            # The server reloaded this scene with changes: its lattice or placement may differ.
            info = self.describe(scene, refresh=True)
            logger.info("scene %s changed on the server (revision %s): described again",
                        info.name, info.revision)  # fmt: skip
            if _revision(reply) != info.revision:  # reloaded once more in between: ask again
                reply = self.request(Op.QUERY, **fields)
        return Frame.from_reply(reply, info)

    def stats(self) -> dict[str, Any]:
        """The server's counters and latency percentiles."""
        return self.request(Op.STATS)

    def ping(self) -> float:
        """One ``ping`` round trip; returns its duration in seconds."""
        start = time.perf_counter()
        self.request(Op.PING)
        return time.perf_counter() - start

    def request(self, op: str, **fields: Any) -> dict[str, Any]:
        """Send one request and return its (successful) reply.

        Fields whose value is None are left out; the session id is added.

        Raises:
            Timeout: No reply within ``timeout`` after ``retries`` re-sends.
            ServerError: The server answered with an error reply (``.code`` says which).
            ProtocolError: The reply was not a valid protocol message.
            MembraneError: The client is closed, or ZeroMQ failed.
        """
        request_id = next(self._ids)
        message = request(op, request_id, session=self.session, **fields)
        return check_reply(self._round_trip(encode(message)), request_id)

    # -- lifecycle ---------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """True once ``close()`` ran."""
        return self._closed

    def close(self) -> None:
        """Close the socket (LINGER 0: returns at once). Safe to call twice."""
        self._discard_socket()
        self._closed = True

    def __enter__(self) -> Client:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        # A forgotten client must not keep a socket that could block the context's term().
        if getattr(self, "_socket", None) is not None:
            self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"Client({self.address!r}, timeout={self.timeout}, scene={self.scene!r}, {state})"

    # -- Lazy Pirate ------------------------------------------------------------------------

    def _round_trip(self, payload: bytes) -> dict[str, Any]:
        if self._closed:
            raise MembraneError("the client is closed")
        attempts = self.retries + 1
        for attempt in range(1, attempts + 1):
            socket = self._socket or self._open_socket()
            self._socket = socket
            try:
                socket.send(payload, copy=True)
                data = socket.recv(copy=True)
            except zmq.Again:
                # The REQ socket is now stuck mid-exchange: throw it away, never reuse it.
                self._discard_socket()
                logger.debug("no reply from %s (attempt %d/%d)", self.address, attempt, attempts)
                continue
            except zmq.ZMQError as exc:
                self._discard_socket()
                raise MembraneError(f"ZeroMQ error talking to {self.address}: {exc}") from None
            return decode(data)
        tries = f" after {attempts} attempts" if attempts > 1 else ""
        raise Timeout(f"no reply from {self.address} within {self.timeout} s{tries}")

    def _open_socket(self) -> zmq.Socket[bytes]:
        socket: zmq.Socket[bytes] = self._context.socket(zmq.REQ)
        socket.setsockopt(zmq.LINGER, 0)
        milliseconds = -1 if self.timeout is None else max(1, round(self.timeout * 1000))
        socket.setsockopt(zmq.RCVTIMEO, milliseconds)
        socket.setsockopt(zmq.SNDTIMEO, milliseconds)
        socket.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)
        for option, value in self._socket_options.items():
            socket.setsockopt(option, value)
        try:
            socket.connect(self.address)
        except zmq.ZMQError as exc:
            socket.close(linger=0)
            raise UserError(f"cannot connect to {self.address!r}: {exc}") from None
        return socket

    def _discard_socket(self) -> None:
        socket, self._socket = self._socket, None
        if socket is not None and not socket.closed:
            socket.close(linger=0)


def _revision(reply: dict[str, Any]) -> str | None:
    """A query reply's scene revision (None from servers that send none)."""
    revision = reply.get("revision")
    return revision if isinstance(revision, str) else None
