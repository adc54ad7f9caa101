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
from abc import ABC, abstractmethod

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

from membrane_models.duhamel import (
    BumpResponse,
    bump_amplitude_factor,
    bump_integral,
    quasi_static_constant,
)
from membrane_models.problems import MembraneForced, StringForced, time_bump
from membrane_models.solution import (
    ExactSolution,
    MemoryBudgetExceeded,
    PointFrames,
    check_budget,
)
from membrane_models.spectrum import GaussianProfile, gaussian_sine_integrals

__all__ = [
    "MAX_CANDIDATES",
    "MAX_MODES",
    "MAX_TABLE",
    "ForcedModalSolution",
    "SineSum",
    "forced_modal_solution",
    "sine_sum",
    "uniform_grid_shape",
]

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
ForcedProblem = StringForced | MembraneForced

MAX_CANDIDATES = 2**21  # modes in the candidate box (bounds memory: a few arrays of this size)
MAX_MODES = 2**16  # modes kept
MAX_TABLE = 2**23  # entries of the Duhamel table (dynamic modes x panels): 128 MiB
_SAMPLES_PER_AXIS = 33  # first-pass sampling grid for the solution's size U
_SAMPLE_TIMES = 65
_FIRST_PASS_SPECTRUM = 1e-6  # first pass: modes down to this fraction of the Gaussian spectrum
_FIRST_PASS_KEEP = 1e-6  # ... and down to this fraction of the largest mode bound
_OUTSIDE_SHARE = 0.1  # share of the error budget allowed outside the candidate box
_QUASI_STATIC_SHARE = 0.1  # share of the error budget spent on quasi-static fast modes
_BLOCK_ELEMENTS = 4 * 2**20  # float64 elements per scratch block in grid / point evaluation
_IBP = 12.0  # the fast-mode constant of bump_amplitude_factor
# Choosing modes holds three box-sized float64/int64 arrays at once (bounds, order, sums).
_SELECT_BYTES_PER_CANDIDATE = 32
_SPECTRUM_BLOCK = 2**16  # mode numbers per block of the closed-form sine integrals
_DENSE_PREFERRED_BYTES = 32 * 2**20  # a dense basis this small is the fastest form per frame
_CHUNK_ELEMENTS = 2**19  # float64 elements of basis per block when recomputed per frame (4 MiB)
_MAX_CHUNKED_SINES = 2**24  # sines per frame beyond which recomputing is too slow (~0.4 s)
_MAX_ONE_OFF_SINES = 2**28  # the same for a sum computed once at load (the static field, ~6 s)
_GRID_TOLERANCE = 1e-15  # points this close to i / N are the uniform grid (linspace rounding)
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
        count, n_static = len(modes), int(quasi_static.sum())
        # modes; coefficients, omega, mask; the dynamic and static index lists; static weights
        held = int(modes.nbytes) + count * (8 + 8 + 1 + 8) + 8 * n_static
        if count > n_static:
            dynamic = modes[~quasi_static].astype(np.float64)
            omega_max = problem.c * math.pi * math.sqrt(float((dynamic**2).sum(axis=1).max()))
            held += BumpResponse.bytes_needed(count - n_static, omega_max, problem.a)
        return held

    def _basis(self, points: FloatArray, modes: IntArray | None = None) -> FloatArray:
        """phi at ``points`` (n, d) for ``modes`` (default all): shape (n, M)."""
        modes = self.modes if modes is None else modes
        return _sine_basis(points, modes, np.empty((points.shape[0], modes.shape[0])))

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
            _left(max_bytes, per_call + field_bytes),
        )
        static_field = self._static_field(points, grid, _left(max_bytes, per_call + dynamic.nbytes))
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
    profiles = _profiles(problem)
    scale = _solution_scale(problem, profiles, max_bytes)
    if scale == 0.0:  # h = 0: nothing moves
        return ForcedModalSolution(problem, np.zeros((0, len(profiles)), np.int64), np.zeros(0), 0)
    budget = rtol * scale
    counts = _candidate_counts(problem, profiles, _OUTSIDE_SHARE * budget)
    outside = _outside_tail(problem, profiles, counts)
    quasi_allowed = _QUASI_STATIC_SHARE * budget
    candidates = math.prod(counts)
    check_budget(
        f"choosing modes among {candidates} candidates",
        _SELECT_BYTES_PER_CANDIDATE * candidates,
        max_bytes,
    )
    modes, coefficients, dropped = _select(
        problem, profiles, counts, budget - outside - quasi_allowed
    )
    quasi_static, quasi_error = _quasi_static_modes(problem, modes, coefficients, quasi_allowed)
    modes, coefficients, quasi_static, over_table = _fit_table(
        problem, modes, coefficients, quasi_static
    )
    _check_series(problem, modes, quasi_static, max_bytes)
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


def _profiles(problem: ForcedProblem) -> tuple[GaussianProfile, ...]:
    if isinstance(problem, MembraneForced):
        return (GaussianProfile(problem.x0, problem.k), GaussianProfile(problem.y0, problem.k))
    return (GaussianProfile(problem.x0, problem.k),)


def _check_series(
    problem: ForcedProblem,
    modes: IntArray,
    quasi_static: NDArray[np.bool_],
    max_bytes: int | None,
    stage: str = "",
) -> None:
    """Refuse a series whose tables would exceed ``max_bytes``, before building them."""
    if max_bytes is None:
        return
    n_dynamic = int((~quasi_static).sum())
    check_budget(
        f"the series{stage} ({len(modes)} modes, a Duhamel table for {n_dynamic} of them)",
        ForcedModalSolution.bytes_needed(problem, modes, quasi_static),
        max_bytes,
    )


def _left(max_bytes: int | None, used: int) -> int | None:
    """What is left of a budget once ``used`` bytes are spoken for (None: no limit)."""
    return None if max_bytes is None else max_bytes - used


def _box_modes(counts: tuple[int, ...]) -> IntArray:
    """All mode numbers of the box 1..counts[0] (x 1..counts[1]): shape (M, d)."""
    axes = [np.arange(1, n + 1, dtype=np.int64) for n in counts]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def _box_coefficients(
    problem: ForcedProblem, profiles: tuple[GaussianProfile, ...], counts: tuple[int, ...]
) -> FloatArray:
    """F = -h 2^d prod I over the box, flattened in ``_box_modes`` order."""
    coefficients = np.array(-problem.h * 2.0 ** len(profiles))
    for profile, n in zip(profiles, counts, strict=True):
        coefficients = np.multiply.outer(coefficients, _profile_coefficients(profile, n))
    return np.asarray(coefficients, dtype=np.float64).ravel()


def _profile_coefficients(profile: GaussianProfile, n: int) -> FloatArray:
    """I_1 .. I_n (``profile.coefficients(n)``) a block at a time: the closed form takes about
    a dozen complex temporaries per mode, 150 MiB for the 1.5 million of a long string box."""
    out = np.empty(n)
    for lo in range(0, n, _SPECTRUM_BLOCK):
        numbers = np.arange(lo + 1, min(n, lo + _SPECTRUM_BLOCK) + 1)
        out[lo : lo + numbers.size] = gaussian_sine_integrals(numbers, profile.x0, profile.k)
    return out


def _mode_bounds(problem: ForcedProblem, modes: IntArray, coefficients: FloatArray) -> FloatArray:
    omega = problem.c * math.pi * np.sqrt((modes.astype(np.float64) ** 2).sum(axis=1))
    return np.abs(coefficients) * bump_amplitude_factor(omega, problem.a)


def _spectral_width(profile: GaussianProfile) -> int:
    """Mode number where the Gaussian spectrum has fallen to ``_FIRST_PASS_SPECTRUM``."""
    return max(
        4, math.ceil(2.0 * math.sqrt(profile.k * math.log(1 / _FIRST_PASS_SPECTRUM)) / math.pi)
    )


def _solution_scale(
    problem: ForcedProblem, profiles: tuple[GaussianProfile, ...], max_bytes: int | None
) -> float:
    """U = max |u| on a sampling grid, from a cheap first-pass series."""
    counts = tuple(_spectral_width(p) for p in profiles)
    while math.prod(counts) > MAX_MODES:
        counts = tuple(max(1, n // 2) for n in counts)
    modes = _box_modes(counts)
    coefficients = _box_coefficients(problem, profiles, counts)
    bounds = _mode_bounds(problem, modes, coefficients)
    if not np.any(bounds > 0.0):
        return 0.0
    keep = bounds >= _FIRST_PASS_KEEP * bounds.max()
    modes, coefficients = modes[keep], coefficients[keep]
    allowed = _FIRST_PASS_KEEP * float(bounds.max())
    quasi_static, _ = _quasi_static_modes(problem, modes, coefficients, allowed)
    # Fast, strong forces (c = 100, k = 1e5) would need gigabytes of table here too; U is an
    # estimate, so the fastest modes go quasi-static (or are left out) beyond MAX_TABLE.
    modes, coefficients, quasi_static, _ = _fit_table(problem, modes, coefficients, quasi_static)
    _check_series(problem, modes, quasi_static, max_bytes, " of the first pass")
    first = ForcedModalSolution(problem, modes, coefficients, math.nan, quasi_static)
    axes = [_sample_axis(p.x0) for p in profiles]
    t = np.union1d(np.linspace(0.0, problem.t_end, _SAMPLE_TIMES), [min(0.5, problem.t_end)])
    return float(np.abs(first.grid(*axes, t)).max())


def _sample_axis(centre: float) -> FloatArray:
    return np.union1d(np.linspace(0.0, 1.0, _SAMPLES_PER_AXIS), [centre])


def _candidate_counts(
    problem: ForcedProblem, profiles: tuple[GaussianProfile, ...], allowed: float
) -> tuple[int, ...]:
    """The smallest box (doubling per axis) whose outside tail bound is within ``allowed``."""
    counts = [_spectral_width(p) for p in profiles]
    while True:
        tails = [_axis_tail(problem, profiles, i, counts[i]) for i in range(len(counts))]
        if sum(tails) <= allowed:
            break
        worst = int(np.argmax(tails))
        if math.prod(counts) * 2 > MAX_CANDIDATES:
            break
        counts[worst] *= 2
    return tuple(counts)


def _outside_tail(
    problem: ForcedProblem, profiles: tuple[GaussianProfile, ...], counts: tuple[int, ...]
) -> float:
    return sum(_axis_tail(problem, profiles, i, n) for i, n in enumerate(counts))


def _axis_tail(
    problem: ForcedProblem, profiles: tuple[GaussianProfile, ...], axis: int, n: int
) -> float:
    """Bound on sum of b over all modes whose number along ``axis`` exceeds ``n``.

    Uses |I_j| <= gamma_j + A / j and b <= |F| 12 / w^2 (derivation in docs/PHYSICS.md).
    """
    own = profiles[axis]
    scale = abs(problem.h) * 2.0 ** len(profiles) * _IBP / (problem.c * math.pi) ** 2
    gauss, ends = own.gauss_tail(n), own.boundary_amplitude
    if len(profiles) == 1:
        return scale * (gauss + ends / 2.0) / n**2
    other_ends = profiles[1 - axis].boundary_amplitude
    log_factor = 1.5 + math.log(n)
    return scale * (
        gauss / n**2  # Gaussian x Gaussian (sum of the other axis' gamma <= 1)
        + ends / (2.0 * n**2)  # boundary x Gaussian
        + other_ends * log_factor * gauss / n**2  # Gaussian x boundary
        + ends * other_ends * (log_factor / (2.0 * n**2) + 1.0 / (4.0 * n**2))  # boundary^2
    )


def _select(
    problem: ForcedProblem,
    profiles: tuple[GaussianProfile, ...],
    counts: tuple[int, ...],
    allowed: float,
) -> tuple[IntArray, FloatArray, float]:
    """Keep the fewest box modes whose dropped bounds sum to at most ``allowed``.

    Works on the flattened box without its mode numbers, three box-sized arrays at a time (the
    box holds up to ``MAX_CANDIDATES``). Returns the kept modes, their coefficients and the sum
    of the dropped bounds.
    """
    bounds = _box_bounds(problem, profiles, counts)
    order = np.argsort(bounds)  # smallest first: the cheapest to drop
    dropped_sums = bounds[order]
    del bounds
    np.cumsum(dropped_sums, out=dropped_sums)
    n_drop = int(np.searchsorted(dropped_sums, max(allowed, 0.0), side="right"))
    n_drop = max(n_drop, len(order) - MAX_MODES)
    dropped = float(dropped_sums[n_drop - 1]) if n_drop else 0.0
    del dropped_sums
    keep = np.sort(order[n_drop:])
    del order
    index = np.unravel_index(keep, counts)  # box order is C order: mode numbers are index + 1
    modes = np.stack([i.astype(np.int64) + 1 for i in index], axis=1)
    # F = ((-h 2^d) I_m) I_n, multiplied in the order _box_coefficients uses: the same bits
    # (I_n is elementwise in n), and I only up to the largest mode number kept.
    coefficients = np.full(keep.size, -problem.h * 2.0 ** len(profiles))
    for profile, i in zip(profiles, index, strict=True):
        largest = int(i.max()) + 1 if i.size else 0
        coefficients = coefficients * _profile_coefficients(profile, largest)[i]
    return modes, coefficients, dropped


def _box_bounds(
    problem: ForcedProblem, profiles: tuple[GaussianProfile, ...], counts: tuple[int, ...]
) -> FloatArray:
    """The bound b of every box mode, flattened in ``_box_modes`` order.

    The same operations as ``_mode_bounds``, done in place: three box-sized arrays at most.
    """
    bounds = _box_coefficients(problem, profiles, counts)
    np.abs(bounds, out=bounds)
    squares = np.zeros(())
    for n in counts:  # m^2 [+ n^2] over the box, exact in float64
        squares = np.add.outer(squares, np.arange(1, n + 1, dtype=np.float64) ** 2)
    omega = np.sqrt(squares.reshape(-1), out=squares.reshape(-1))
    omega *= problem.c * math.pi
    factor = bump_integral(problem.a) / omega  # min(G1 / w, 12 / w^2): bump_amplitude_factor
    np.square(omega, out=omega)
    np.divide(_IBP, omega, out=omega)
    np.minimum(factor, omega, out=factor)
    del omega, squares
    bounds *= factor
    return bounds


def _quasi_static_modes(
    problem: ForcedProblem, modes: IntArray, coefficients: FloatArray, allowed: float
) -> tuple[NDArray[np.bool_], float]:
    """Mark the fastest modes whose quasi-static errors |F| E2 / w^3 sum to at most ``allowed``.

    Returns the mask and the sum of the marked modes' error bounds.
    """
    mask = np.zeros(len(modes), dtype=bool)
    constant = quasi_static_constant(problem.a)
    if constant is None or len(modes) == 0:
        return mask, 0.0
    omega = problem.c * math.pi * np.sqrt((modes.astype(np.float64) ** 2).sum(axis=1))
    errors = np.abs(coefficients) * constant / omega**3
    order = np.argsort(-omega)  # fastest first
    sums = np.cumsum(errors[order])
    n_static = int(np.searchsorted(sums, allowed, side="right"))
    mask[order[:n_static]] = True
    return mask, float(sums[n_static - 1]) if n_static else 0.0


def _fit_table(
    problem: ForcedProblem,
    modes: IntArray,
    coefficients: FloatArray,
    quasi_static: NDArray[np.bool_],
) -> tuple[IntArray, FloatArray, NDArray[np.bool_], float]:
    """Keep the Duhamel table within ``MAX_TABLE`` entries.

    The table holds (dynamic modes) x (panels), panels growing with the fastest dynamic mode.
    Dynamic modes beyond the limit, fastest first, become quasi-static (a >= 2) or are dropped.
    Returns the modes, coefficients, mask and the added error bound (absolute).
    """
    omega = problem.c * math.pi * np.sqrt((modes.astype(np.float64) ** 2).sum(axis=1))
    dynamic = np.flatnonzero(~quasi_static)
    order = dynamic[np.argsort(omega[dynamic])]  # slowest first
    panels = BumpResponse.panels_needed(omega[order], problem.a)
    fits = np.arange(1, order.size + 1) * panels <= MAX_TABLE
    n_fit = int(np.argmin(fits)) if not fits.all() else order.size
    excess = order[n_fit:]
    if excess.size == 0:
        return modes, coefficients, quasi_static, 0.0
    constant = quasi_static_constant(problem.a)
    if constant is not None:
        quasi_static = quasi_static.copy()
        quasi_static[excess] = True
        added = float((np.abs(coefficients[excess]) * constant / omega[excess] ** 3).sum())
        return modes, coefficients, quasi_static, added
    added = float(_mode_bounds(problem, modes[excess], coefficients[excess]).sum())
    keep = np.setdiff1d(np.arange(len(modes)), excess)
    return modes[keep], coefficients[keep], quasi_static[keep], added


# -- sums of sine modes at fixed points ------------------------------------------------------


class SineSum(ABC):
    """sum_k a_k s_k phi_k(points) for amplitudes a, fixed points, modes and scales s.

    phi_k = prod over axes of sin(m_k pi x); ``s`` is folded in once (None: 1).

    Attributes:
        method: the form's name (``dense``, ``grid``, ``chunked``).
        nbytes: bytes it holds plus the most scratch a call takes.
    """

    method: str
    nbytes: int

    @abstractmethod
    def __call__(self, amplitudes: FloatArray) -> FloatArray:
        """The sum at every point, shape (n,), for amplitudes (K,)."""


class DenseSineSum(SineSum):
    """The basis (n, K) cached, scales folded in: one matrix-vector product per call."""

    method = "dense"

    def __init__(self, points: FloatArray, modes: IntArray, scale: FloatArray | None) -> None:
        n, count = points.shape[0], modes.shape[0]
        self._basis = np.empty((n, count))
        rows = _rows_per_block(count, points.shape[1])
        scratch = np.empty((min(rows, n), count)) if points.shape[1] > 1 else None
        for lo in range(0, n, rows):  # in place, block by block: no (n, K) temporaries
            block = self._basis[lo : lo + rows]
            _sine_basis(points[lo : lo + rows], modes, block, _rows(scratch, len(block)))
        del scratch
        if scale is not None:
            self._basis *= scale[None, :]
        self.nbytes = self.bytes_needed(n, count)

    @staticmethod
    def bytes_needed(n: int, count: int) -> int:
        """The basis, and the product's result."""
        return 8 * n * count + 8 * n

    def __call__(self, amplitudes: FloatArray) -> FloatArray:
        return np.asarray(self._basis @ amplitudes)


class GridSineSum(SineSum):
    """On the uniform grid x_i = i / N, i = 0 .. N per axis (x-major), by a sine transform.

    sin(m pi i / N) is 2N-periodic in m, odd about m = N and 0 at m = 0 and N, so each mode
    adds its amplitude (with a sign) to one of the mode numbers 1 .. N - 1 per axis; on the
    interior points sum_k b_k sin(k pi i / N) is DST-I (scipy: y_i = 2 sum_k b_k sin(...), so
    the weights carry 1/2 per axis). Edge points are 0 exactly. Nothing of size n x K is held.
    """

    method = "grid"

    def __init__(self, shape: tuple[int, ...], modes: IntArray, scale: FloatArray | None) -> None:
        self._shape = shape
        self._inner = tuple(max(0, size - 2) for size in shape)
        self._interior = tuple(slice(1, size - 1) for size in shape)
        bins, signs, alive = _fold_modes(shape, modes)
        weights = signs * 0.5 ** len(shape)
        self._weights = weights if scale is None else weights * scale[alive]
        self._bins, self._alive = bins, alive
        self.nbytes = self.bytes_needed(shape, modes.shape[0])

    @staticmethod
    def bytes_needed(shape: tuple[int, ...], count: int) -> int:
        """Bins, weights and indices per mode (and their product per call); a few arrays of the
        grid's size per call (the folded amplitudes, the transform's buffers, the frame)."""
        return 40 * count + 48 * math.prod(shape)

    def __call__(self, amplitudes: FloatArray) -> FloatArray:
        out = np.zeros(self._shape)
        size = math.prod(self._inner)
        if size and self._bins.size:
            folded = np.bincount(
                self._bins, weights=self._weights * amplitudes[self._alive], minlength=size
            )
            out[self._interior] = scipy.fft.dstn(folded.reshape(self._inner), type=1)
        return out.reshape(-1)


class ChunkedSineSum(SineSum):
    """The basis recomputed block by block at every call: memory one block, time n x K sines."""

    method = "chunked"

    def __init__(self, points: FloatArray, modes: IntArray, scale: FloatArray | None) -> None:
        self._points, self._modes, self._scale = points, modes, scale
        self._rows = min(points.shape[0], _rows_per_block(modes.shape[0], points.shape[1]))
        self.nbytes = self.bytes_needed(points.shape[0], modes.shape[0], points.shape[1])

    @staticmethod
    def bytes_needed(n: int, count: int, dims: int) -> int:
        """One block of basis (and its second factor), the weights, the result."""
        rows = min(n, _rows_per_block(count, dims))
        return 8 * rows * count * min(dims, 2) + 8 * count + 8 * n

    def __call__(self, amplitudes: FloatArray) -> FloatArray:
        weights = amplitudes if self._scale is None else self._scale * amplitudes
        points, count = self._points, self._modes.shape[0]
        out = np.empty(points.shape[0])
        block = np.empty((self._rows, count))
        scratch = np.empty((self._rows, count)) if points.shape[1] > 1 else None
        for lo in range(0, points.shape[0], self._rows):
            rows = points[lo : lo + self._rows]
            basis = _sine_basis(rows, self._modes, block[: len(rows)], _rows(scratch, len(rows)))
            out[lo : lo + len(rows)] = basis @ weights
        return out


def sine_sum(
    points: FloatArray,
    modes: IntArray,
    scale: FloatArray | None,
    grid: tuple[int, ...] | None,
    max_bytes: int | None,
    max_sines: int = _MAX_CHUNKED_SINES,
) -> SineSum:
    """The fastest form of sum_k a_k s_k phi_k(points) that fits in ``max_bytes``.

    Args:
        points: (n, d) points.
        modes: (K, d) mode numbers.
        scale: (K,) factors s_k, or None.
        grid: ``uniform_grid_shape(points)``.
        max_bytes: most memory the form may hold and use per call (None: no limit).
        max_sines: most sines a call may compute (the chunked form's cost).

    Raises:
        MemoryBudgetExceeded: no form fits (the figure is the least that would do).
    """
    n, count, dims = points.shape[0], modes.shape[0], points.shape[1]
    limit = math.inf if max_bytes is None else max_bytes
    dense = DenseSineSum.bytes_needed(n, count)
    if dense <= min(limit, _DENSE_PREFERRED_BYTES):
        return DenseSineSum(points, modes, scale)
    if grid is not None and GridSineSum.bytes_needed(grid, count) <= limit:
        return GridSineSum(grid, modes, scale)
    if dense <= limit:
        return DenseSineSum(points, modes, scale)
    feasible = [dense]
    if grid is not None:
        feasible.append(GridSineSum.bytes_needed(grid, count))
    sines = n * count * dims
    if sines <= max_sines:
        chunked = ChunkedSineSum.bytes_needed(n, count, dims)
        if chunked <= limit:
            return ChunkedSineSum(points, modes, scale)
        feasible.append(chunked)
    slow = ""
    if sines > max_sines:  # say why recomputing per call is no way out
        slow = f" (recomputed per call: {sines} sines, more than {max_sines})"
    raise MemoryBudgetExceeded(
        f"the values of {count} modes at {n} points{slow}", min(feasible), int(limit)
    )


def uniform_grid_shape(points: FloatArray) -> tuple[int, ...] | None:
    """(nx[, ny]) when ``points`` (n, d) are the x-major grid of linspace(0, 1, .) axes."""
    n, dims = points.shape
    if n == 0 or dims > 2:
        return None
    if dims == 1:
        shape: tuple[int, ...] = (n,)
    else:
        changes = np.flatnonzero(points[:, 0] != points[0, 0])
        ny = int(changes[0]) if changes.size else n
        if n % ny:
            return None
        shape = (n // ny, ny)
    axes = np.meshgrid(*(np.linspace(0.0, 1.0, size) for size in shape), indexing="ij")
    for axis, expected in enumerate(axes):
        if np.abs(points[:, axis] - expected.reshape(-1)).max() > _GRID_TOLERANCE:
            return None
    return shape


def _fold_modes(shape: tuple[int, ...], modes: IntArray) -> tuple[IntArray, FloatArray, IntArray]:
    """Each mode's bin among the grid's interior mode numbers, its sign, and which modes count.

    Returns (bins, signs, alive): flat bins into the (N_x - 1[, N_y - 1]) array of folded mode
    numbers, +-1, and the indices of the modes not zero on the whole grid.
    """
    bins = np.zeros(modes.shape[0], dtype=np.int64)
    signs = np.ones(modes.shape[0])
    alive = np.ones(modes.shape[0], dtype=bool)
    for axis, size in enumerate(shape):
        intervals = size - 1  # N: points i / N, i = 0 .. N
        if intervals < 2:  # no interior point on this axis: every value is 0
            alive[:] = False
            continue
        folded = modes[:, axis] % (2 * intervals)
        mirrored = folded > intervals
        folded = np.where(mirrored, 2 * intervals - folded, folded)
        signs = np.where(mirrored, -signs, signs)
        alive &= (folded != 0) & (folded != intervals)
        bins = bins * (intervals - 1) + (folded - 1)
    kept = np.flatnonzero(alive)
    return bins[kept], signs[kept], kept


def _rows_per_block(count: int, dims: int) -> int:
    """Points per block so that a block of basis (and its second factor) is ``_CHUNK_ELEMENTS``."""
    return max(1, _CHUNK_ELEMENTS // max(1, count * min(dims, 2)))


def _rows(array: FloatArray | None, rows: int) -> FloatArray | None:
    return None if array is None else array[:rows]


def _sine_basis(
    points: FloatArray, modes: IntArray, out: FloatArray, scratch: FloatArray | None = None
) -> FloatArray:
    """phi = prod over axes of sin(pi x m) into ``out`` (n, K), in place.

    The same operations as sin(pi * outer(x, m)) per axis, so the same bits, without their
    temporaries; ``scratch`` (n, K) holds the second axis' factor (allocated when None).
    """
    _axis_sines(points[:, 0], modes[:, 0], out)
    for axis in range(1, points.shape[1]):
        factor = np.empty_like(out) if scratch is None else scratch
        _axis_sines(points[:, axis], modes[:, axis], factor)
        out *= factor
    return out


def _axis_sines(x: FloatArray, m: IntArray, out: FloatArray) -> None:
    np.multiply.outer(x, m, out=out)
    np.multiply(np.pi, out, out=out)
    np.sin(out, out=out)
