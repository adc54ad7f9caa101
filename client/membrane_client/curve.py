"""CurveZMQ keys for a client: the socket options that authenticate it to a server.

Keys live in files made by ``membrane keys DIR NAME`` (the format of
``zmq.auth.create_certificates``: ``NAME.key`` holds a public key, ``NAME.key_secret`` both keys,
readable by its owner only). A client needs the server's public key and its own secret file;
its public key must be in the server's directory of allowed clients::

    from membrane_client import Client
    from membrane_client.curve import client_socket_options

    options = client_socket_options("keys/server.key", "keys/client.key_secret")
    with Client("tcp://robot-host:5555", socket_options=options) as client:
        frame = client.query(0.25)

Needs pyzmq only (``zmq.auth`` ships with it). The server side is ``membrane_server.security``.
"""

from __future__ import annotations

import logging
import stat
from pathlib import Path

import zmq
import zmq.auth
from zmq.utils import z85

from membrane_errors import UserError

__all__ = [
    "CurveError",
    "SocketOptions",
    "client_socket_options",
    "load_keypair",
    "load_public_key",
]

SocketOptions = dict[int, int | bytes]

_Z85_KEY_CHARS = 40

logger = logging.getLogger(__name__)


class CurveError(UserError):
    """A key file that cannot be used (the message names it and why)."""


def client_socket_options(server_key_file: str | Path, secret_file: str | Path) -> SocketOptions:
    """Socket options for ``Client(..., socket_options=...)`` to talk to a CurveZMQ server.

    Args:
        server_key_file: The server's public key (its ``.key`` file; a ``.key_secret`` file
            works too, only its public key is read).
        secret_file: The client's own ``.key_secret`` file.

    Raises:
        CurveError: A file is missing, unreadable, or (for ``secret_file``) holds no secret key.
    """
    server_public = load_public_key(server_key_file)
    public, secret = load_keypair(secret_file, "client")
    return {
        zmq.CURVE_SERVERKEY: server_public,
        zmq.CURVE_PUBLICKEY: public,
        zmq.CURVE_SECRETKEY: secret,
    }


def load_public_key(path: str | Path) -> bytes:
    """The public key in a ``.key`` or ``.key_secret`` file (Z85 text, as bytes)."""
    public, _ = _load_certificate(path)
    return public


def load_keypair(path: str | Path, whose: str) -> tuple[bytes, bytes]:
    """(public, secret) from a ``.key_secret`` file; ``whose`` names the owner in errors."""
    public, secret = _load_certificate(path)
    if secret is None:
        raise CurveError(
            f"{path}: holds no secret key (the {whose} needs its .key_secret file, not .key)"
        )
    _warn_if_exposed(Path(path))
    return public, secret


def _warn_if_exposed(secret_file: Path) -> None:
    mode = secret_file.stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        logger.warning(
            "%s: secret key readable by others (mode %s); run: chmod 600 %s",
            secret_file, oct(stat.S_IMODE(mode)), secret_file,
        )  # fmt: skip


def _load_certificate(path: str | Path) -> tuple[bytes, bytes | None]:
    file = Path(path)
    if not file.is_file():
        raise CurveError(f"{file}: no such key file")
    try:
        public, secret = zmq.auth.load_certificate(file)
    except (OSError, ValueError) as exc:  # ValueError: "No public key found in ..."
        raise CurveError(f"{file}: not a ZeroMQ certificate ({exc})") from None
    for key in (public, secret):
        if key is not None and not _is_curve_key(key):
            raise CurveError(f"{file}: not a ZeroMQ certificate (a key is not 40 Z85 characters)")
    return public, secret


def _is_curve_key(key: bytes) -> bool:
    # zmq.auth reads whatever text is quoted; libzmq needs 32 bytes, Z85-encoded as 40 characters.
    if len(key) != _Z85_KEY_CHARS:
        return False
    try:
        z85.decode(key)
    except (ValueError, KeyError, TypeError):
        return False
    return True
