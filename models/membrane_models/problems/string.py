"""The string problems: forced (the study's C = 10, force at x = 0.8) and plucked."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.problems.base import InvalidProblem, Problem, check_inside
from membrane_models.problems.forcing import ForcedMixin, time_bump
from membrane_models.problems.string_shapes import pluck

__all__ = ["StringForced", "StringKirchhoff", "StringPlucked"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class StringForced(ForcedMixin, Problem):
    """u_tt = c^2 u_xx + f on x in [0, 1]; u = 0 at both ends; u = u_t = 0 at t = 0.

    f(x, t) = -h exp(-k (x - x0)^2) g_a(t), with g_a the time bump (zero outside t in [0, 1]).
    """

    name: ClassVar[str] = "string-forced"
    spatial_dims: ClassVar[int] = 1
    equation: ClassVar[str] = "u_tt = c^2 u_xx + f"

    c: float = 10.0
    t_end: float = 1.0
    x0: float = 0.8

    def _check(self) -> None:
        self._check_force()
        check_inside("x0", self.x0)

    def force_space(self, x: ArrayLike) -> FloatArray:
        """The spatial profile -h exp(-k (x - x0)^2)."""
        x = np.asarray(x, dtype=np.float64)
        return -self.h * np.exp(-self.k * (x - self.x0) ** 2)

    def forcing(self, x: ArrayLike, t: ArrayLike) -> FloatArray:
        """f(x, t), broadcasting x against t."""
        return self.force_space(x) * time_bump(t, self.a)

    def force_profile(self, coords: Sequence[ArrayLike]) -> FloatArray:
        """``force_space`` with its one axis given as a sequence (``ForcedProblem``)."""
        (x,) = coords
        return self.force_space(x)


@dataclass(frozen=True)
class StringPlucked(Problem):
    """u_tt = c^2 u_xx on x in [0, 1]; u = 0 at both ends; free vibration from a pluck.

    Initial shape: a triangle of height ``height`` with its apex at ``x0`` (kinked), or, when
    ``smoothing`` > 0, that triangle mollified by a Gaussian of standard deviation ``smoothing``
    (applied to its odd periodic extension, so the ends stay fixed). Zero initial velocity.
    The default t_end = 2 is one period (2 / c).
    """

    name: ClassVar[str] = "string-plucked"
    spatial_dims: ClassVar[int] = 1
    equation: ClassVar[str] = "u_tt = c^2 u_xx"

    c: float = 1.0
    t_end: float = 2.0
    height: float = 0.05
    x0: float = 0.3
    smoothing: float = 0.0

    def _check(self) -> None:
        check_inside("x0", self.x0)
        if self.smoothing < 0.0:
            raise InvalidProblem(f"smoothing must be >= 0, got {self.smoothing}")

    def triangle(self, x: ArrayLike) -> FloatArray:
        """The unsmoothed pluck: rises linearly to ``height`` at x0, falls back to 0 at x = 1."""
        x = np.asarray(x, dtype=np.float64)
        rising = self.height * x / self.x0
        falling = self.height * (1.0 - x) / (1.0 - self.x0)
        return np.where(x <= self.x0, rising, falling)


@dataclass(frozen=True)
class StringKirchhoff(Problem):
    """u_tt = (c^2 + stretch S(t)) u_xx, S = int_0^1 u_x^2 dx: the Kirchhoff-Carrier string, whose
    tension grows with its stretch (a slack rope at large amplitude), freed from a pluck.

    Initial shape: the first ``MODES`` sine modes of the triangle of ``height`` with its apex at
    ``x0``, smoothed by a Gaussian of standard deviation ``smoothing`` (``string_shapes.pluck``);
    zero initial velocity. Shapes within those modes evolve within them exactly, so the
    Galerkin reference (``exact.kirchhoff_carrier``) solves this problem, not an approximation
    of it, to its integrator's tolerance. ``stretch`` = 0 is the linear plucked string.
    """

    name: ClassVar[str] = "string-kirchhoff"
    spatial_dims: ClassVar[int] = 1
    equation: ClassVar[str] = "u_tt = (c^2 + stretch int u_x^2 dx) u_xx"
    MODES: ClassVar[int] = 64

    c: float = 1.0
    t_end: float = 2.0
    stretch: float = 100.0
    height: float = 0.05
    x0: float = 0.3
    smoothing: float = 0.02

    def _check(self) -> None:
        check_inside("x0", self.x0)
        if self.smoothing < 0.0:
            raise InvalidProblem(f"smoothing must be >= 0, got {self.smoothing}")
        if self.stretch < 0.0:
            raise InvalidProblem(f"stretch must be >= 0, got {self.stretch}")

    def initial_modes(self) -> FloatArray:
        """The initial shape's sine coefficients, modes 1 .. ``MODES``."""
        return self.height * pluck(self.x0, self.MODES, self.smoothing)
