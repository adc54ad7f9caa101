"""What the forced problems share: the bump in time g_a(t) and the Gaussian force's parameters.

The forced string and membrane are driven by f = profile(x[, y]) g_a(t); training samples the
force through ``ForcedProblem`` and the exact solutions integrate ``time_bump`` in closed form.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.problems.base import InvalidProblem, check_positive

__all__ = ["ForcedMixin", "ForcedProblem", "time_bump"]

FloatArray = NDArray[np.float64]


def time_bump(t: ArrayLike, a: float) -> FloatArray:
    """The forcing's time factor 4^a t^(a-1) (1-t)^(a-1) on [0, 1], zero outside.

    It peaks at t = 0.5 with the value 4 (for any a) and vanishes at both ends for a > 1.
    """
    t = np.asarray(t, dtype=np.float64)
    inside = (t >= 0.0) & (t <= 1.0)
    tc = np.where(inside, t, 0.5)  # keeps the powers finite where the mask is off
    # Computed through logs: 4^a overflows nothing, but t^(a-1) underflows gracefully this way.
    if a == 1.0:  # t^0 (1-t)^0 = 1, also at the ends (where 0 * log 0 would give NaN)
        return np.where(inside, 4.0, 0.0)
    with np.errstate(divide="ignore"):
        log_g = a * math.log(4.0) + (a - 1.0) * (np.log(tc) + np.log1p(-tc))
    return np.where(inside, np.exp(log_g), 0.0)


@runtime_checkable
class ForcedProblem(Protocol):
    """A problem driven by f = profile(x[, y]) g_a(t): what training samples of its force.

    The forced string and membrane share it; their profiles take one coordinate array per space
    axis, hence ``force_profile(coords)`` with the axes as a sequence.
    """

    @property
    def h(self) -> float: ...

    @property
    def a(self) -> float: ...

    def force_profile(self, coords: Sequence[ArrayLike]) -> FloatArray:
        """The spatial profile at one coordinate array per space axis (broadcast together)."""
        ...


@dataclass(frozen=True)
class ForcedMixin:
    """Parameters of the Gaussian-in-space, bump-in-time force f = -h exp(-k r^2) g_a(t)."""

    h: float = 1.0
    a: float = 8.9
    k: float = 400.0

    def _check_force(self) -> None:
        check_positive("k", self.k)
        if self.a < 1.0:
            raise InvalidProblem(f"a must be >= 1 (the time factor t^(a-1) blows up), got {self.a}")
