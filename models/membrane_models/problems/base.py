"""The problems: wave equations on unit domains, as typed, validated objects.

Each problem is a frozen dataclass holding its physical parameters with the reference study's
defaults. ``make_problem(name, overrides)`` builds one from its registry name and ``NAME=VALUE``
overrides (strings, as typed at the command line); invalid values raise ``InvalidProblem``
(a ``ValueError``) with a message that names the parameter.

Conventions: nondimensional, spatial domain [0, 1] (the unit interval or the unit square), time
domain [0, t_end], fixed (zero) displacement on the whole boundary.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from membrane_errors import UserError

__all__ = ["InvalidProblem", "Problem", "check_finite", "check_inside", "check_positive"]

FloatArray = NDArray[np.float64]


class InvalidProblem(UserError):
    """A problem name or parameter value that cannot be used."""


def check_finite(problem: object) -> None:
    for f in fields(problem):  # type: ignore[arg-type]
        value = getattr(problem, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise InvalidProblem(f"{f.name} must be a finite number, got {value}")


def check_positive(name: str, value: float) -> None:
    if not value > 0.0:
        raise InvalidProblem(f"{name} must be > 0, got {value}")


def check_inside(name: str, value: float) -> None:
    if not 0.0 < value < 1.0:
        raise InvalidProblem(f"{name} must lie inside the domain (0, 1), got {value}")


@dataclass(frozen=True)
class Problem:
    """Common parts of every problem. Subclasses add their parameters and checks."""

    name: ClassVar[str]
    spatial_dims: ClassVar[int]
    equation: ClassVar[str]

    c: float
    t_end: float

    def __post_init__(self) -> None:
        check_finite(self)
        check_positive("c", self.c)
        check_positive("t_end", self.t_end)
        self._check()

    def _check(self) -> None:
        """Problem-specific checks (override)."""

    @property
    def axes(self) -> tuple[str, ...]:
        """Names of the input axes, space first: ('x', 't') or ('x', 'y', 't')."""
        return ("x", "t") if self.spatial_dims == 1 else ("x", "y", "t")

    def parameters(self) -> dict[str, float]:
        """The parameters as plain data (for manifests and .npz files)."""
        return {k: float(v) for k, v in asdict(self).items()}

    def with_overrides(self, overrides: dict[str, str]) -> Problem:
        """A copy with ``NAME=VALUE`` overrides applied (values as strings or numbers).

        Names are case-insensitive, so ``C=10`` (the study's spelling) sets ``c``.
        """
        known = {f.name for f in fields(self)}
        parsed: dict[str, float] = {}
        for name, raw in overrides.items():
            key = name.strip().lower()
            if key not in known:
                raise InvalidProblem(
                    f"{self.name} has no parameter {key!r}; known: {', '.join(sorted(known))}"
                )
            try:
                parsed[key] = float(raw)
            except (TypeError, ValueError):
                raise InvalidProblem(f"{key} must be a number, got {raw!r}") from None
        return replace(self, **parsed)
