"""The interface every exact solution offers, and the input checks they share.

An ``ExactSolution`` answers three kinds of question about u(x[, y], t):

``grid(x, t)`` / ``grid(x, y, t)``
    values on a tensor grid, shaped (nx, nt) or (nx, ny, nt);
``at_points(points, t)``
    values at scattered points (n, d) for a vector of times, shaped (n, nt);
``on_points(points, max_bytes)``
    a frame function for a fixed set of points: everything spatial is computed once, so that
    each later call ``frame(t)`` returns the (n,) displacements cheaply.

Points must lie in the closed unit domain; times may be any finite numbers (before t = 0 the
system is at rest in its initial state).

Memory is stated, so that a server can count it against a budget: ``memory_bytes`` is what a
solution holds (a series' tables), ``PointFrames.nbytes`` what a frame function holds plus the
scratch one call uses. Given ``max_bytes``, solutions evaluate in a form that fits (see
``modal``) or raise ``MemoryBudgetExceeded`` with the figure, before allocating it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_errors import UserError
from membrane_models.problems import Problem

__all__ = [
    "ExactSolution",
    "FrameFunction",
    "InvalidQuery",
    "PointFrames",
]

FloatArray = NDArray[np.float64]
FrameFunction = Callable[[float], FloatArray]

# Points this far outside [0, 1] are still accepted (rounding in lattices built by callers).
_DOMAIN_SLACK = 1e-12


class InvalidQuery(UserError):
    """Points or times an exact solution cannot be evaluated at."""


@dataclass(frozen=True)
class PointFrames:
    """A frame function on fixed points, ``frame(t) -> (n,)``, and the memory it takes.

    Attributes:
        compute: the function.
        nbytes: bytes it holds between calls plus the most scratch one call allocates.
        method: how its spatial part is evaluated (``dense``, ``grid``, ``chunked``,
            ``closed form``), for reports.
    """

    compute: FrameFunction
    nbytes: int
    method: str

    def __call__(self, t: float) -> FloatArray:
        return self.compute(t)


class ExactSolution(ABC):
    """An exact (or truncated-series) solution of one problem.

    Attributes:
        problem: the problem solved.
        n_modes: number of series terms used (0 for a closed form).
        truncation_error: bound (or, where documented, estimate) of the relative error made by
            truncating the series: sup over space-time of |truncated tail| divided by the
            largest |u| found on a sampling grid. 0 for a closed form.
    """

    problem: Problem
    n_modes: int
    truncation_error: float

    @property
    def spatial_dims(self) -> int:
        """1 for the string, 2 for the membrane."""
        return self.problem.spatial_dims

    @abstractmethod
    def at_points(self, points: ArrayLike, t: ArrayLike) -> FloatArray:
        """u at ``points`` (n, d), columns x[, y], for times ``t`` (nt,): shape (n, nt)."""

    @abstractmethod
    def on_points(self, points: ArrayLike, max_bytes: int | None = None) -> PointFrames:
        """A function ``frame(t) -> (n,)`` for fixed ``points`` (n, d), cheap per call.

        Args:
            points: (n, d) points in the unit domain.
            max_bytes: most memory the function may hold and use per call (None: no limit).

        Raises:
            MemoryBudgetExceeded: no way of evaluating fits in ``max_bytes``.
        """

    @property
    def memory_bytes(self) -> int:
        """Bytes the solution itself holds (a series' tables); 0 for closed forms."""
        return 0

    def grid(self, *axes: ArrayLike) -> FloatArray:
        """u on the tensor grid of ``x, t`` (string) or ``x, y, t`` (membrane).

        Returns shape (nx, nt) or (nx, ny, nt).
        """
        if len(axes) != self.spatial_dims + 1:
            names = ", ".join(self.problem.axes)
            raise InvalidQuery(f"{self.problem.name}: grid takes ({names}), got {len(axes)} axes")
        spatial = [self.check_axis(a, name) for a, name in zip(axes[:-1], "xy", strict=False)]
        t = self.check_times(axes[-1])
        mesh = np.meshgrid(*spatial, indexing="ij")
        points = np.stack([m.ravel() for m in mesh], axis=1)
        values = self.at_points(points, t)
        return values.reshape(*(len(s) for s in spatial), len(t))

    # -- input checks shared by the implementations ---------------------------------------

    def check_points(self, points: ArrayLike) -> FloatArray:
        """``points`` as a finite (n, d) float64 array inside the unit domain."""
        d = self.spatial_dims
        array = np.asarray(points, dtype=np.float64)
        if d == 1 and array.ndim == 1:
            array = array[:, None]
        if array.ndim != 2 or array.shape[1] != d:
            raise InvalidQuery(
                f"{self.problem.name}: points must have shape (n, {d}), got {array.shape}"
            )
        return self._inside_domain(array, "points")

    def check_axis(self, values: ArrayLike, name: str) -> FloatArray:
        """A 1-D coordinate axis inside [0, 1]."""
        array = np.atleast_1d(np.asarray(values, dtype=np.float64))
        if array.ndim != 1:
            raise InvalidQuery(f"{self.problem.name}: axis {name} must be 1-D")
        return self._inside_domain(array, f"axis {name}")

    def _inside_domain(self, array: FloatArray, what: str) -> FloatArray:
        if not np.all(np.isfinite(array)):
            raise InvalidQuery(f"{self.problem.name}: {what} must be finite")
        if array.size and (array.min() < -_DOMAIN_SLACK or array.max() > 1.0 + _DOMAIN_SLACK):
            raise InvalidQuery(f"{self.problem.name}: {what} must lie in the unit domain [0, 1]")
        return np.clip(array, 0.0, 1.0)

    def check_times(self, t: ArrayLike) -> FloatArray:
        """``t`` as a finite 1-D float64 array."""
        array = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if array.ndim != 1:
            raise InvalidQuery(f"{self.problem.name}: t must be a scalar or 1-D, got {array.shape}")
        if not np.all(np.isfinite(array)):
            raise InvalidQuery(f"{self.problem.name}: times must be finite")
        return array

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.problem.name}, n_modes={self.n_modes}, "
            f"truncation_error={self.truncation_error:.2g})"
        )
