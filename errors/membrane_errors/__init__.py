"""The root of every exception membrane raises, in a package every other one may import.

Two branches decide what a user sees:

- ``UserError``: bad input (a flag out of range, a scene file that does not validate, a request
  the server refuses). The ``membrane`` command prints it in one line and exits with code 2.
- Any other ``MembraneError``: the job itself failed for a reason outside the program (no reply
  from the server, a simulator that went away, an export that misses its parity bound). One line,
  exit code 1.

Anything that is not a ``MembraneError`` is a bug: the command prints its traceback and exits
with code 1. ``UserError`` is also a ``ValueError``, so code that guards a call with
``except ValueError`` keeps working.

This package holds the two roots only (no dependencies), so that the client, which imports
nothing else of ours, and the models, which import neither the server nor the client, share them.
"""

from __future__ import annotations

__all__ = ["MembraneError", "UserError"]


class MembraneError(Exception):
    """Base class of every error membrane raises on purpose."""


class UserError(MembraneError, ValueError):
    """Bad input from the user or a peer: reported in one line (exit code 2 at the CLI)."""
