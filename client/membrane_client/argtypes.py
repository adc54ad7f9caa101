"""Argument types for the command line: numbers checked where argparse reads them.

Each factory returns a converter for ``add_argument(type=...)``; a bad value becomes argparse's
one-line usage error (exit code 2).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["bounded_float", "bounded_int"]


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
