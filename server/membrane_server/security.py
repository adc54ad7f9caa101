"""CurveZMQ: authentication and encryption for a server bound beyond loopback.

Keys live in files made by ``zmq.auth.create_certificates`` (a ``NAME.key`` file holds a public
key, ``NAME.key_secret`` both keys)::

    python -c "import zmq.auth; zmq.auth.create_certificates('keys', 'server')"
    python -c "import zmq.auth; zmq.auth.create_certificates('keys', 'client')"

The server reads its secret file and a directory of the public keys of the clients it allows
(``server_socket_options``, ``CurveAuthenticator``); a client reads the server's public key and
its own secret file (``client_socket_options``: ``membrane_client.curve``'s, re-exported here).
A client whose key is not in the directory, or that speaks no Curve at all, never completes the
handshake: it gets no reply and its request times out.

This module needs pyzmq only (``zmq.auth`` ships with it).
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import TracebackType

import zmq
from zmq.auth.thread import ThreadAuthenticator

from membrane_client.curve import (
    CurveError,
    SocketOptions,
    client_socket_options,
    load_keypair,
    load_public_key,
)

__all__ = [
    "CurveAuthenticator",
    "CurveError",
    "SocketOptions",
    "client_socket_options",
    "is_loopback_endpoint",
    "server_socket_options",
]

logger = logging.getLogger(__name__)


def server_socket_options(secret_file: str | Path) -> SocketOptions:
    """Socket options that make a server socket a CurveZMQ server with these keys.

    Args:
        secret_file: The server's ``.key_secret`` file.

    Raises:
        CurveError: The file is missing, unreadable, or holds no secret key.
    """
    public, secret = load_keypair(secret_file, "server")
    return {zmq.CURVE_SERVER: 1, zmq.CURVE_PUBLICKEY: public, zmq.CURVE_SECRETKEY: secret}


def is_loopback_endpoint(endpoint: str) -> bool:
    """True when a bind endpoint is reachable from this machine only (loopback, ipc, inproc).

    Anything else (``tcp://0.0.0.0:...``, ``tcp://*:...``, an interface name or address) can be
    reached from the network, and deserves CurveZMQ.
    """
    transport, _, rest = endpoint.partition("://")
    if transport in ("ipc", "inproc"):
        return True
    host = rest.rsplit(":", 1)[0].strip("[]")
    return host in ("localhost", "::1") or host.startswith("127.")


class CurveAuthenticator:
    """Admits only the clients whose public keys are in a directory (a ZAP handler thread).

    Start it before the server binds, on the server's ZeroMQ context; stop it after the server
    stopped. Usable as a context manager.

    Args:
        clients_dir: Directory of allowed client public keys (``*.key`` files).
        context: The server's ZeroMQ context (default: the process-wide shared one, which is
            what ``Server`` uses by default).

    Raises:
        CurveError: The directory is missing or holds no public key.
    """

    def __init__(
        self,
        clients_dir: str | Path,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
    ) -> None:
        self.clients_dir = Path(clients_dir)
        self.allowed = _count_public_keys(self.clients_dir)
        self._context = context or zmq.Context.instance()
        self._thread: ThreadAuthenticator | None = None

    def start(self) -> None:
        """Start the ZAP handler; from now on Curve sockets of this context check client keys."""
        if self._thread is not None:
            raise RuntimeError("the authenticator is already running")
        thread = ThreadAuthenticator(self._context, log=logger)
        thread.start()
        thread.configure_curve(domain="*", location=str(self.clients_dir))
        self._thread = thread
        logger.info("CurveZMQ: %d allowed client key(s) from %s", self.allowed, self.clients_dir)

    def stop(self) -> None:
        """Stop the ZAP handler (idempotent)."""
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.stop()

    def __enter__(self) -> CurveAuthenticator:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop()


def _count_public_keys(directory: Path) -> int:
    if not directory.is_dir():
        raise CurveError(f"{directory}: no such directory of client public keys")
    keys = [p for p in directory.glob("*.key") if p.is_file()]
    if not keys:
        raise CurveError(f"{directory}: holds no client public key (*.key); nobody could connect")
    for key in keys:  # a malformed file would be skipped silently by the authenticator
        load_public_key(key)
    return len(keys)
