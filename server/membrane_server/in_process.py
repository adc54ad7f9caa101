"""A Client transport that hands each request to a Dispatcher in this process: no sockets.

For tests of the client against the real dispatcher, and for embedding a scene in a Python
simulator loop without a server process::

    from membrane_client import Client
    from membrane_server.dispatch import Dispatcher
    from membrane_server.served import ServedScene
    from membrane_server.in_process import InProcessTransport

    transport = InProcessTransport(Dispatcher([ServedScene.load("rope")]))
    with Client("in-process://rope", transport=transport) as client:
        frame = client.query(0.25)
"""

from __future__ import annotations

from collections.abc import Callable

from membrane_server.dispatch import Dispatcher

__all__ = ["InProcessTransport"]


class InProcessTransport:
    """``membrane_client.transport.Transport`` over a Dispatcher's ``handle``."""

    def __init__(self, dispatcher: Dispatcher, peer: str = "") -> None:
        self.dispatcher = dispatcher
        self.peer = peer  # who the dispatcher is told sent each request (e.g. "key:...")

    def round_trip(self, payload: bytes, stale: Callable[[bytes], bool] | None = None) -> bytes:
        """The dispatcher's reply to ``payload`` (it never raises: errors are replies; in one
        process no reply can be stale)."""
        return self.dispatcher.handle([payload], self.peer).reply

    def close(self) -> None:
        """Nothing to release: the dispatcher belongs to the caller."""
