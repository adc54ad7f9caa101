"""The membrane problem: the study's forced unit square (C = 5, force at (0.8, 0.5))."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.problems.base import Problem, check_inside
from membrane_models.problems.forcing import ForcedMixin, time_bump

__all__ = ["MembraneForced"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MembraneForced(ForcedMixin, Problem):
    """z_tt = c^2 (z_xx + z_yy) + f on [0, 1]^2; z = 0 on the edges; z = z_t = 0 at t = 0.

    f(x, y, t) = -h exp(-k ((x - x0)^2 + (y - y0)^2)) g_a(t).
    """

    name: ClassVar[str] = "membrane-forced"
    spatial_dims: ClassVar[int] = 2
    equation: ClassVar[str] = "z_tt = c^2 (z_xx + z_yy) + f"

    c: float = 5.0
    t_end: float = 1.0
    x0: float = 0.8
    y0: float = 0.5

    def _check(self) -> None:
        self._check_force()
        check_inside("x0", self.x0)
        check_inside("y0", self.y0)

    def force_space(self, x: ArrayLike, y: ArrayLike) -> FloatArray:
        """The spatial profile -h exp(-k ((x - x0)^2 + (y - y0)^2)), broadcasting x against y."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return -self.h * np.exp(-self.k * ((x - self.x0) ** 2 + (y - self.y0) ** 2))

    def forcing(self, x: ArrayLike, y: ArrayLike, t: ArrayLike) -> FloatArray:
        """f(x, y, t), broadcasting x, y and t."""
        return self.force_space(x, y) * time_bump(t, self.a)

    def force_profile(self, coords: Sequence[ArrayLike]) -> FloatArray:
        """``force_space`` with its two axes given as a sequence (``ForcedProblem``)."""
        x, y = coords
        return self.force_space(x, y)
