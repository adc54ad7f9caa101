"""What every subcommand checks its arguments with: ``UsageError`` and bounded number types.

Each factory returns a converter for ``add_argument(type=...)``; a bad value becomes argparse's
one-line usage error (exit code 2). Checks argparse cannot express (flags that go together, a
file's suffix) raise ``UsageError``, which the dispatcher reports the same way.

Imports nothing of ours but ``membrane_errors``: every package's commands may use it.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from membrane_errors import UserError

__all__ = ["UsageError", "bounded_float", "bounded_int"]


class UsageError(UserError):
    """Bad input at the command line: reported in one line, exit code 2."""


def bounded_float(
    minimum: float | None = None, *, exclusive: bool = False
) -> Callable[[str], float]:
    """A finite float, >= ``minimum`` (> when ``exclusive``); any finite float when None."""

    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text}")
        if minimum is not None and (value <= minimum if exclusive else value < minimum):
            if exclusive and minimum == 0:
                raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
            relation = ">" if exclusive else ">="
            raise argparse.ArgumentTypeError(f"must be {relation} {minimum:g}, got {text}")
        return value

    return convert


def bounded_int(minimum: int, maximum: int | None = None, *, why: str = "") -> Callable[[str], int]:
    """An integer in [minimum, maximum] (no upper bound when None); ``why`` explains the bound."""

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            bound = f"in {minimum}..{maximum}" if maximum is not None else f">= {minimum}"
            reason = f" ({why})" if why else ""
            raise argparse.ArgumentTypeError(f"must be {bound}{reason}, got {text}")
        return value

    return convert
