"""The live engine's errors: bad input, refused before anything changes.

States are immutable values, so an error can never leave a half-applied step behind: the
caller keeps the state it passed in. Every class is a ``membrane_errors.UserError`` (and so a
``ValueError``): the server turns them into an error reply, the CLI into one line.
"""

from __future__ import annotations

from membrane_errors import UserError

__all__ = [
    "InvalidEngineSettings",
    "InvalidGrasp",
    "InvalidLoad",
    "InvalidProbe",
    "InvalidShape",
    "InvalidState",
    "InvalidTool",
    "LiveError",
]


class LiveError(UserError):
    """Bad input to a live engine; the state passed in is untouched."""


class InvalidEngineSettings(LiveError):
    """An engine cannot be built with these settings (dt, damping, lattice, modes)."""


class InvalidLoad(LiveError):
    """A load ``{at, force, radius}`` that cannot be applied."""


class InvalidProbe(LiveError):
    """A probe ``{at, depth, radius}`` that cannot be applied."""


class InvalidGrasp(LiveError):
    """A grasp ``{at, height, radius}`` that cannot be held."""


class InvalidTool(LiveError):
    """A rigid tool ``{kind, at, depth, radius}`` that cannot be applied."""


class InvalidShape(LiveError):
    """An initial displacement or velocity that cannot be projected on the modes."""


class InvalidState(LiveError):
    """A state that does not belong to this engine."""
