"""Exact solutions of the plucked string: d'Alembert's formula and the Fourier series.

The string starts at rest from the pluck shape p(x) (a triangle of height H with its apex at x0,
or that triangle smoothed). With fixed ends the solution is d'Alembert's

    u(x, t) = (P(x - c t) + P(x + c t)) / 2,

where P is the odd, 2-periodic extension of p. For the triangle P is piecewise linear, so this is
exact to rounding. The smoothed pluck is P convolved with a Gaussian of standard deviation
sigma; since a symmetric kernel leaves linear pieces unchanged, the convolution only differs from
P near its kinks, by a closed-form Gaussian-smoothed ramp per kink (``_smoothed_ramp_excess``).

The same solution as a Fourier series (separation of variables, zero initial velocity):

    u(x, t) = sum_n C_n exp(-(n pi sigma)^2 / 2) cos(n pi c t) sin(n pi x),
    C_n = 2 H sin(n pi x0) / ((n pi)^2 x0 (1 - x0)),

where the Gaussian factor is the smoothing's effect on mode n. For the kinked triangle the
coefficients decay like 1/n^2 only, so the series converges slowly; it is the cross-check of the
closed form, not the reference. Times before 0 give the initial (held) shape.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr

from membrane_models.budget import check_budget
from membrane_models.exact.solution import ExactSolution, PointFrames
from membrane_models.problems import StringPlucked

__all__ = ["MAX_FOURIER_MODES", "PluckedDAlembert", "PluckedFourier", "pluck_extension"]

FloatArray = NDArray[np.float64]

MAX_FOURIER_MODES = 4096
_KERNEL_REACH = 40.0  # kinks farther than this many sigmas contribute below exp(-800)
_BLOCK_ELEMENTS = 4 * 2**20
# d'Alembert's frame: about this many (n,) float64 temporaries alive at once per call.
_CLOSED_FORM_ARRAYS = 16


def _smoothed_ramp_excess(s: FloatArray, sigma: float) -> FloatArray:
    """(ramp * Gaussian)(s) - ramp(s) = sigma phi(s / sigma) - |s| Phi(-|s| / sigma)."""
    z = np.abs(s) / sigma
    return np.asarray(sigma * np.exp(-0.5 * z**2) / math.sqrt(2.0 * math.pi) - np.abs(s) * ndtr(-z))


def pluck_extension(problem: StringPlucked, x: ArrayLike) -> FloatArray:
    """P(x): the odd 2-periodic extension of the pluck shape (smoothed when sigma > 0)."""
    x = np.asarray(x, dtype=np.float64)
    height, x0, sigma = problem.height, problem.x0, problem.smoothing
    s = np.mod(x + 1.0, 2.0) - 1.0  # in [-1, 1)
    values = np.sign(s) * problem.triangle(np.abs(s))
    if sigma == 0.0:
        return np.asarray(values)
    # Slope jumps: -H/(x0(1-x0)) at the apex x0 (mod 2), +H/(x0(1-x0)) at its mirror -x0.
    jump = height / (x0 * (1.0 - x0))
    reach = 1 + math.ceil(_KERNEL_REACH * sigma / 2.0)
    for j in range(-reach, reach + 1):
        values = values - jump * _smoothed_ramp_excess(s - (x0 + 2 * j), sigma)
        values = values + jump * _smoothed_ramp_excess(s - (-x0 + 2 * j), sigma)
    return np.asarray(values)


class PluckedDAlembert(ExactSolution):
    """d'Alembert's closed form: exact to rounding (n_modes = 0, truncation_error = 0)."""

    problem: StringPlucked

    def __init__(self, problem: StringPlucked) -> None:
        self.problem = problem
        self.n_modes = 0
        self.truncation_error = 0.0

    def _values(self, x: FloatArray, t: FloatArray) -> FloatArray:
        shift = self.problem.c * np.maximum(t, 0.0)
        left = pluck_extension(self.problem, x[:, None] - shift[None, :])
        right = pluck_extension(self.problem, x[:, None] + shift[None, :])
        return 0.5 * (left + right)

    def at_points(self, points: ArrayLike, t: ArrayLike) -> FloatArray:
        x = self.check_points(points)[:, 0]
        return self._values(x, self.check_times(t))

    def on_points(self, points: ArrayLike, max_bytes: int | None = None) -> PointFrames:
        x = self.check_points(points)[:, 0]
        nbytes = 8 * _CLOSED_FORM_ARRAYS * x.size  # nothing cached: the formula's temporaries
        check_budget(f"d'Alembert's frames at {x.size} points", nbytes, max_bytes)

        def frame(t: float) -> FloatArray:
            return self._values(x, np.array([float(t)]))[:, 0]

        return PointFrames(frame, nbytes, "closed form")


class PluckedFourier(ExactSolution):
    """The Fourier series, truncated so that its stated error bound is at most ``rtol``.

    The tail bound is sum_{n > N} |C_n| exp(-(n pi sigma)^2 / 2) <= 2 H exp(-(N pi sigma)^2 / 2)
    / (pi^2 x0 (1 - x0) N), stated relative to H. For the kinked triangle (sigma = 0) reaching a
    small rtol would take billions of modes: N stops at ``max_modes`` and the achieved bound is
    stated.
    """

    problem: StringPlucked

    def __init__(
        self, problem: StringPlucked, rtol: float = 1e-10, max_modes: int = MAX_FOURIER_MODES
    ) -> None:
        if not (math.isfinite(rtol) and rtol > 0.0):
            raise ValueError(f"rtol must be a positive number, got {rtol}")
        if max_modes < 1:
            raise ValueError(f"max_modes must be >= 1, got {max_modes}")
        self.problem = problem
        self.n_modes = self._modes_needed(rtol, max_modes)
        self.truncation_error = self._tail_bound(self.n_modes)
        n = np.arange(1, self.n_modes + 1, dtype=np.float64)
        x0, sigma = problem.x0, problem.smoothing
        self.coefficients = (
            2.0 * problem.height * np.sin(n * np.pi * x0) / ((n * np.pi) ** 2 * x0 * (1.0 - x0))
        ) * np.exp(-0.5 * (n * np.pi * sigma) ** 2)
        self.omega = n * np.pi * problem.c
        self._wavenumbers = n * np.pi

    def _tail_bound(self, n: int) -> float:
        """Bound on the dropped terms after n modes, relative to the pluck height."""
        x0, sigma = self.problem.x0, self.problem.smoothing
        return 2.0 * math.exp(-0.5 * (n * math.pi * sigma) ** 2) / (math.pi**2 * x0 * (1 - x0) * n)

    def _modes_needed(self, rtol: float, max_modes: int) -> int:
        n = 1
        while self._tail_bound(n) > rtol and n < max_modes:
            n = min(2 * n, max_modes)
        lo, hi = max(1, n // 2), n  # smallest n meeting rtol lies in (n/2, n]
        while lo < hi and self._tail_bound(hi) <= rtol:
            mid = (lo + hi) // 2
            if self._tail_bound(mid) <= rtol:
                hi = mid
            else:
                lo = mid + 1
        return hi

    def _basis(self, x: FloatArray) -> FloatArray:
        return np.sin(np.outer(x, self._wavenumbers))

    def at_points(self, points: ArrayLike, t: ArrayLike) -> FloatArray:
        x = self.check_points(points)[:, 0]
        t = np.maximum(self.check_times(t), 0.0)
        amplitudes = self.coefficients[:, None] * np.cos(np.outer(self.omega, t))
        out = np.empty((x.size, t.size))
        block = max(1, _BLOCK_ELEMENTS // self.n_modes)
        for lo in range(0, x.size, block):
            out[lo : lo + block] = self._basis(x[lo : lo + block]) @ amplitudes
        return out

    def on_points(self, points: ArrayLike, max_bytes: int | None = None) -> PointFrames:
        x = self.check_points(points)[:, 0]
        # A cross-check, not served: its (n, N) basis is built whole, or refused up front.
        nbytes = 8 * x.size * (self.n_modes + 1)
        what = f"the Fourier series' {self.n_modes} modes at {x.size} points"
        check_budget(what, 2 * nbytes, max_bytes)  # the basis and a temporary while it is built
        weighted_basis = self._basis(x) * self.coefficients[None, :]

        def frame(t: float) -> FloatArray:
            return np.asarray(weighted_basis @ np.cos(self.omega * max(float(t), 0.0)))

        return PointFrames(frame, 2 * nbytes, "dense")
