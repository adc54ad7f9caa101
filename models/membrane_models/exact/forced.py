"""Exact solutions of the forced string and membrane: sine-mode series with Duhamel integrals.

With fixed edges the modes are products of sines, phi(x[, y]) = sin(m pi x) [sin(n pi y)], with
angular frequencies w = c pi sqrt(m^2 [+ n^2]). The force f = -h G(x)[G(y)] g_a(t) projects onto
each mode with the coefficient F = -h 2^d I_m [I_n] (see ``spectrum``), and each mode amplitude
obeys q'' + w^2 q = F g_a(t) from rest, solved exactly by ``duhamel.BumpResponse``:

    u(x, t) = sum_modes F q(t; w) phi(x).

Choosing the modes. A mode can never exceed b = |F| min(G1 / w, 12 / w^2) in magnitude (see
``duhamel.bump_amplitude_factor``), and |phi| <= 1, so dropping a set of modes changes u by at
most the sum of their b anywhere in space-time. The solver

1. estimates the solution's size U = max |u| on a sampling grid, from the modes inside the
   Gaussian's spectral width (a cheap first pass);
2. takes every mode of a candidate box large enough that the rigorous bound on everything
   outside it (``_outside_tail``) is at most a tenth of the budget rtol * U;
3. keeps the fewest candidates whose dropped b sum, plus that outside bound, stays within
   rtol * U.

Fast modes respond quasi-statically: |q(t) - g(t) / w^2| <= E2 / w^3 (``duhamel.
quasi_static_constant``). The fastest kept modes, as many as a tenth of the budget allows, are
evaluated that way; their sum is one precomputed spatial field times g(t), which keeps the
Duhamel table small (its size grows with the fastest mode it holds) and frames cheap.

The stated ``truncation_error`` is (dropped b + outside bound + quasi-static bound) / U: a bound
on the sup-norm error relative to the largest sampled |u|. Memory is bounded: at most
``MAX_CANDIDATES`` in the box, ``MAX_MODES`` kept, ``MAX_TABLE`` Duhamel table entries (beyond
it the fastest modes are made quasi-static, or dropped when a < 2; the first pass too). When a
limit stops the solver short of rtol (a force centred very close to an edge has a slowly
decaying spectrum) the error achieved is stated instead, and a warning is logged.

Memory is also stated, and checked before it is allocated when a budget ``max_bytes`` is given
(``MemoryBudgetExceeded`` names the figure): choosing modes takes about
``_SELECT_BYTES_PER_CANDIDATE`` bytes per candidate for a moment, the solution then holds its
Duhamel table (``memory_bytes``; at most 128 MiB). Frames on fixed points (``on_points``) need
the modes' values there, ``sine_sum`` chooses how:

- ``dense``: the (points x modes) basis, cached, one matrix-vector product per frame; when it is
  small (``_DENSE_PREFERRED_BYTES``), or fits and nothing below does;
- ``grid``: on the uniform grid x_i = i / N of a scene's lattice, sin(m pi i / N) is 2N-periodic
  and odd in m about N, so the modes fold onto 1 .. N - 1 and a frame is one type-I discrete
  sine transform (DST-I), O(modes + points log points), nothing of size points x modes;
- ``chunked``: otherwise the basis recomputed block by block per frame, while that stays under
  ``_MAX_CHUNKED_SINES`` sines; beyond it (say 65,536 scattered points and thousands of modes)
  the frames are refused with the figure.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.budget import check_budget
from membrane_models.exact.duhamel import (
    BumpResponse,
)
from membrane_models.exact.mode_selection import (
    candidate_counts,
    check_series,
    fit_table,
    force_profiles,
    left,
    outside_tail,
    quasi_static_modes,
    select,
    series_bytes,
    solution_scale,
)
from membrane_models.exact.solution import (
    ExactSolution,
    PointFrames,
)
from membrane_models.problems import MembraneForced, StringForced, time_bump
from membrane_models.sines import sine_basis, sine_sum, uniform_grid_shape

__all__ = ["ForcedModalSolution", "forced_modal_solution"]

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
ForcedProblem = StringForced | MembraneForced

_OUTSIDE_SHARE = 0.1  # share of the error budget allowed outside the candidate box
_QUASI_STATIC_SHARE = 0.1  # share of the error budget spent on quasi-static fast modes
_BLOCK_ELEMENTS = 4 * 2**20  # float64 elements per scratch block in grid / point evaluation
# Choosing modes holds three box-sized float64/int64 arrays at once (bounds, order, sums).
_SELECT_BYTES_PER_CANDIDATE = 32
_MAX_ONE_OFF_SINES = 2**28  # the same for a sum computed once at load (the static field, ~6 s)
# Scratch of one frame besides its spatial form: BumpResponse.at's complex temporaries per
# dynamic mode, and the frame's own arrays per point.
_FRAME_BYTES_PER_MODE = 128
_FRAME_BYTES_PER_POINT = 16


class ForcedModalSolution(ExactSolution):
    """A truncated sine-mode series for a forced problem.

    Args:
        problem: the forced string or membrane.
        modes: mode numbers, shape (M, d), entries >= 1.
        coefficients: the force's projection F on each mode, shape (M,).
        truncation_error: the stated relative truncation error (see module docstring).
        quasi_static: mask (M,) of modes evaluated as F g(t) / w^2; default none.
    """

    problem: ForcedProblem

    def __init__(
        self,
        problem: ForcedProblem,
        modes: IntArray,
        coefficients: FloatArray,
        truncation_error: float,
        quasi_static: NDArray[np.bool_] | None = None,
    ) -> None:
        self.problem = problem
        self.modes = np.asarray(modes, dtype=np.int64).reshape(-1, problem.spatial_dims)
        self.coefficients = np.asarray(coefficients, dtype=np.float64)
        self.omega = problem.c * math.pi * np.sqrt((self.modes.astype(np.float64) ** 2).sum(1))
        self.n_modes = int(self.modes.shape[0])
        self.truncation_error = float(truncation_error)
        if quasi_static is None:
            quasi_static = np.zeros(self.n_modes, dtype=bool)
        self.quasi_static = np.asarray(quasi_static, dtype=bool)
        self._dynamic = np.flatnonzero(~self.quasi_static)
        self._static = np.flatnonzero(self.quasi_static)
        # Static deflection per unit g: F / w^2 for the quasi-static modes.
        self._static_weights = self.coefficients[self._static] / self.omega[self._static] ** 2
        self._response = (
            BumpResponse(self.omega[self._dynamic], problem.a) if self._dynamic.size else None
        )

    def amplitudes(self, t: ArrayLike) -> FloatArray:
        """Modal amplitudes F q(t), shape (M, nt)."""
        t = self.check_times(t)
        q = np.empty((self.n_modes, t.size))
        if self._response is not None:
            q[self._dynamic] = self.coefficients[self._dynamic, None] * self._response(t)
        q[self._static] = np.outer(self._static_weights, time_bump(t, self.problem.a))
        return q

    @property
    def memory_bytes(self) -> int:
        arrays = (self.modes, self.coefficients, self.omega, self.quasi_static, self._dynamic,
                  self._static, self._static_weights)  # fmt: skip
        held = sum(int(array.nbytes) for array in arrays)
        return held + (self._response.nbytes if self._response is not None else 0)

    @staticmethod
    def bytes_needed(
        problem: ForcedProblem, modes: IntArray, quasi_static: NDArray[np.bool_]
    ) -> int:
        """What a solution with these modes will hold (``memory_bytes``), before building it."""
        return series_bytes(problem, modes, quasi_static)

    def _basis(self, points: FloatArray, modes: IntArray | None = None) -> FloatArray:
        """phi at ``points`` (n, d) for ``modes`` (default all): shape (n, M)."""
        modes = self.modes if modes is None else modes
        return sine_basis(points, modes, np.empty((points.shape[0], modes.shape[0])))

    def at_points(self, points: ArrayLike, t: ArrayLike) -> FloatArray:
        points = self.check_points(points)
        q = self.amplitudes(t)
        out = np.empty((points.shape[0], q.shape[1]))
        block = max(1, _BLOCK_ELEMENTS // max(1, self.n_modes))
        for lo in range(0, points.shape[0], block):
            out[lo : lo + block] = self._basis(points[lo : lo + block]) @ q
        return out

    def on_points(self, points: ArrayLike, max_bytes: int | None = None) -> PointFrames:
        points = self.check_points(points)
        grid = uniform_grid_shape(points)
        n_dynamic = self._dynamic.size
        per_call = _FRAME_BYTES_PER_POINT * points.shape[0] + _FRAME_BYTES_PER_MODE * n_dynamic
        field_bytes = 8 * points.shape[0]
        # The per-frame form first: if nothing fits, refuse before the static field's work.
        dynamic = sine_sum(
            points,
            self.modes[self._dynamic],
            self.coefficients[self._dynamic],
            grid,
            left(max_bytes, per_call + field_bytes),
        )
        static_field = self._static_field(points, grid, left(max_bytes, per_call + dynamic.nbytes))
        response, a = self._response, self.problem.a

        def frame(t: float) -> FloatArray:
            t = float(t)
            values = static_field * float(time_bump(t, a))
            if response is not None:
                values = values + dynamic(response.at(t))
            return values

        nbytes = static_field.nbytes + dynamic.nbytes + per_call
        return PointFrames(frame, nbytes, dynamic.method)

    def _static_field(
        self, points: FloatArray, grid: tuple[int, ...] | None, max_bytes: int | None
    ) -> FloatArray:
        """sum over the quasi-static modes of F / w^2 phi at ``points``: shape (n,)."""
        if self._static.size == 0:
            return np.zeros(points.shape[0])
        modes = self.modes[self._static]
        summed = sine_sum(points, modes, None, grid, max_bytes, max_sines=_MAX_ONE_OFF_SINES)
        return summed(self._static_weights)

    def grid(self, *axes: ArrayLike) -> FloatArray:
        if len(axes) != self.spatial_dims + 1:
            return super().grid(*axes)  # raises the uniform error
        spatial = [self.check_axis(a, name) for a, name in zip(axes[:-1], "xy", strict=False)]
        t = self.check_times(axes[-1])
        if self.spatial_dims == 1:
            return self.at_points(spatial[0][:, None], t)
        return self._membrane_grid(spatial[0], spatial[1], t)

    def _membrane_grid(self, x: FloatArray, y: FloatArray, t: FloatArray) -> FloatArray:
        """Separable evaluation: sum_mn sin(m pi x) sin(n pi y) Q_mn(t) as two tensor products."""
        out = np.zeros((x.size, y.size, t.size))
        if self.n_modes == 0:
            return out
        mx, my = int(self.modes[:, 0].max()), int(self.modes[:, 1].max())
        sin_x = np.sin(np.pi * np.outer(x, np.arange(1, mx + 1)))
        sin_y = np.sin(np.pi * np.outer(y, np.arange(1, my + 1)))
        block = max(1, _BLOCK_ELEMENTS // (mx * my))
        for lo in range(0, t.size, block):
            ts = t[lo : lo + block]
            dense = np.zeros((mx, my, ts.size))
            dense[self.modes[:, 0] - 1, self.modes[:, 1] - 1] = self.amplitudes(ts)
            along_y = np.tensordot(sin_y, dense, axes=([1], [1]))  # (ny, mx, nt)
            out[:, :, lo : lo + block] = np.tensordot(sin_x, along_y, axes=([1], [1]))
        return out


def forced_modal_solution(
    problem: ForcedProblem, rtol: float = 1e-10, max_bytes: int | None = None
) -> ForcedModalSolution:
    """The modal series of a forced problem, truncated at relative error ``rtol``.

    Args:
        problem: a ``StringForced`` or ``MembraneForced``.
        rtol: target bound on sup |truncation error| / max |u| (see the module docstring).
        max_bytes: most memory the solver may take, choosing modes or holding its table
            (None: only the fixed limits above).

    Raises:
        MemoryBudgetExceeded: a stage would need more than ``max_bytes`` (checked before it
            allocates; the series is never silently cut to fit).
    """
    if not (math.isfinite(rtol) and rtol > 0.0):
        raise ValueError(f"rtol must be a positive number, got {rtol}")
    started = time.perf_counter()
    profiles = force_profiles(problem)
    scale = solution_scale(problem, profiles, max_bytes, ForcedModalSolution)
    if scale == 0.0:  # h = 0: nothing moves
        return ForcedModalSolution(problem, np.zeros((0, len(profiles)), np.int64), np.zeros(0), 0)
    budget = rtol * scale
    counts = candidate_counts(problem, profiles, _OUTSIDE_SHARE * budget)
    outside = outside_tail(problem, profiles, counts)
    quasi_allowed = _QUASI_STATIC_SHARE * budget
    candidates = math.prod(counts)
    check_budget(
        f"choosing modes among {candidates} candidates",
        _SELECT_BYTES_PER_CANDIDATE * candidates,
        max_bytes,
    )
    modes, coefficients, dropped = select(
        problem, profiles, counts, budget - outside - quasi_allowed
    )
    quasi_static, quasi_error = quasi_static_modes(problem, modes, coefficients, quasi_allowed)
    modes, coefficients, quasi_static, over_table = fit_table(
        problem, modes, coefficients, quasi_static
    )
    check_series(problem, modes, quasi_static, max_bytes)
    error = (dropped + outside + quasi_error + over_table) / scale
    if error > rtol:
        logger.warning(
            "%s: truncation error %.2g exceeds rtol %.2g (memory limits reached: box %s, %d modes)",
            problem.name,
            error,
            rtol,
            counts,
            len(modes),
        )
    solution = ForcedModalSolution(problem, modes, coefficients, error, quasi_static)
    logger.debug(
        "%s: %d modes (%d quasi-static) from a %s box, truncation error %.2g, %.3f s",
        problem.name,
        len(modes),
        int(quasi_static.sum()),
        counts,
        error,
        time.perf_counter() - started,
    )
    return solution


# -- mode selection --------------------------------------------------------------------------
