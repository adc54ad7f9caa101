"""The client's exceptions, on membrane's one tree (``membrane_errors``): library errors are
converted at the boundary, so a caller catches ``MembraneError`` and nothing else."""

from __future__ import annotations

from membrane_errors import MembraneError, UserError

__all__ = ["MembraneError", "ProtocolError", "ServerError", "StepLost", "Timeout", "UserError"]


class Timeout(MembraneError):
    """No reply arrived within the client's timeout (after its retries, if any)."""


class StepLost(Timeout):
    """A step's reply was lost on every retry; the session then asked the server what became
    of it. ``applied``: whether the server took the step (True: its frame is lost, ``k`` moved
    on; False: not taken; None: the server could not be asked either). ``k``: the session's step
    count as the server has it (the index of the next step), or None when it was not asked.
    The Session's ``k`` follows the server's; where it could not ask, the next step re-sends
    step k under the same token, which the server answers from its store if it took it."""

    def __init__(self, message: str, applied: bool | None, k: int | None) -> None:
        super().__init__(message)
        self.applied, self.k = applied, k


class ProtocolError(MembraneError):
    """A message that does not follow the wire protocol (undecodable, wrong shape or version)."""


class ServerError(MembraneError):
    """The server answered with an error reply: its ``code`` (an ``ErrorCode`` value, as a
    str) and its one-line ``message``."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code, self.message = code, message
