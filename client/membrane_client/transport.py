"""How a Client's request bytes reach a server: ZeroMQ REQ with the zguide's Lazy Pirate.

After a timeout a REQ socket can neither send nor receive: it is closed and a fresh one opened
for the next attempt. Every socket has LINGER 0, so closing never waits on undelivered messages.
A reply the caller calls ``stale`` (one to an earlier request: a late duplicate of a re-send,
which a relay between client and server may deliver to the newer socket) is a lost reply too:
the socket is replaced and the request re-sent, never the stale reply handed up.
A Client takes any ``Transport``: tests and embedders may hand requests to a dispatcher in the
same process instead (``membrane_server.in_process``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Protocol

import zmq

from membrane_client.errors import MembraneError, Timeout, UserError
from membrane_client.protocol import MAX_REPLY_BYTES

__all__ = ["LazyPirate", "Transport"]

logger = logging.getLogger(__name__)


class Transport(Protocol):
    """Carries one request's bytes to a server and returns the reply's bytes."""

    def round_trip(self, payload: bytes, stale: Callable[[bytes], bool] | None = None) -> bytes:
        """Send ``payload``, return the reply (raises Timeout or MembraneError); a reply
        ``stale`` picks is not the answer (see the module docstring)."""
        ...

    def close(self) -> None:
        """Release what the transport holds; safe to call twice."""
        ...


class LazyPirate:
    """A REQ socket, replaced by a fresh one for each of ``retries`` re-sends after a timeout
    (the arguments are ``Client``'s; a malformed address fails at once)."""

    def __init__(
        self,
        address: str,
        timeout: float | None,
        retries: int,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
        socket_options: Mapping[int, int | bytes] | None = None,
    ) -> None:
        self.address = address
        self.timeout = timeout
        self.retries = retries if timeout is not None else 0
        self._context = context or zmq.Context.instance()
        self._socket_options = dict(socket_options or {})
        self._socket: zmq.Socket[bytes] | None = self._open_socket()

    def round_trip(self, payload: bytes, stale: Callable[[bytes], bool] | None = None) -> bytes:
        attempts = self.retries + 1
        for attempt in range(1, attempts + 1):
            socket = self._socket or self._open_socket()
            self._socket = socket
            try:
                socket.send(payload, copy=True)
                reply = socket.recv(copy=True)
                if stale is None or not stale(reply):
                    return reply
                self.close()  # an earlier request's late duplicate: as good as lost
                logger.debug("stale reply from %s (attempt %d/%d)", self.address, attempt, attempts)
            except zmq.Again:
                # The REQ socket is now stuck mid-exchange: throw it away, never reuse it.
                self.close()
                logger.debug("no reply from %s (attempt %d/%d)", self.address, attempt, attempts)
            except zmq.ZMQError as exc:
                self.close()
                raise MembraneError(f"ZeroMQ error talking to {self.address}: {exc}") from None
        tries = f" after {attempts} attempts" if attempts > 1 else ""
        raise Timeout(f"no reply from {self.address} within {self.timeout} s{tries}")

    def close(self) -> None:
        socket, self._socket = self._socket, None
        if socket is not None and not socket.closed:
            socket.close(linger=0)

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
