"""The flags that say which server to talk to, and how: one definition for every subcommand.

`membrane query`, `ping`, `stats`, `bench` and `coppelia` all take ``--connect`` (default
``DEFAULT_ADDRESS``, the client's), ``--timeout`` and the CurveZMQ key files.
"""

from __future__ import annotations

import argparse

from membrane_cli.arguments import UsageError, bounded_float
from membrane_client.client import DEFAULT_ADDRESS, Client
from membrane_client.curve import SocketOptions, client_socket_options

__all__ = ["add_connection_arguments", "connect", "curve_options"]


def add_connection_arguments(
    parser: argparse.ArgumentParser, *, timeout: float = 2.0, curve: bool = True
) -> None:
    """Add ``--connect`` and ``--timeout`` (and the CurveZMQ key flags when ``curve``)."""
    parser.add_argument(
        "--connect",
        default=DEFAULT_ADDRESS,
        metavar="ADDR",
        help=f"server endpoint (default {DEFAULT_ADDRESS})",
    )
    parser.add_argument(
        "--timeout",
        type=bounded_float(0, exclusive=True),
        default=timeout,
        metavar="S",
        help=f"seconds to wait for each reply (default {timeout:g})",
    )
    if not curve:
        return
    parser.add_argument(
        "--curve-server-key",
        metavar="FILE",
        help="CurveZMQ: the server's public .key file (with --curve-secret)",
    )
    parser.add_argument(
        "--curve-secret",
        metavar="FILE",
        help="CurveZMQ: this client's .key_secret file (with --curve-server-key)",
    )


def curve_options(args: argparse.Namespace) -> SocketOptions | None:
    """CurveZMQ socket options from --curve-server-key/--curve-secret (None without them)."""
    server_key = getattr(args, "curve_server_key", None)
    secret = getattr(args, "curve_secret", None)
    if server_key is None and secret is None:
        return None
    if server_key is None or secret is None:
        raise UsageError("--curve-server-key and --curve-secret go together")
    return client_socket_options(server_key, secret)  # CurveError (a UserError): exit 2


def connect(args: argparse.Namespace, scene: str | None = None) -> Client:
    """A Client for the connection flags in ``args``."""
    return Client(
        args.connect, timeout=args.timeout, scene=scene, socket_options=curve_options(args)
    )
