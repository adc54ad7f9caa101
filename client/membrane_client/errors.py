"""The client's exceptions, on membrane's one tree (``membrane_errors``): library errors are
converted at the boundary, so a caller catches ``MembraneError`` and nothing else."""

from __future__ import annotations

from membrane_errors import MembraneError, UserError

__all__ = ["MembraneError", "ProtocolError", "ServerError", "Timeout", "UserError"]


class Timeout(MembraneError):
    """No reply arrived within the client's timeout (after its retries, if any)."""


class ProtocolError(MembraneError):
    """A message that does not follow the wire protocol (undecodable, wrong shape or version)."""


class ServerError(MembraneError):
    """The server answered with an error reply: its ``code`` (an ``ErrorCode`` value, as a
    str) and its one-line ``message``."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code, self.message = code, message
