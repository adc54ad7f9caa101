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
it the fastest modes are made quasi-static, or dropped when a < 2). When a limit stops the
solver short of rtol (a force centred very close to an edge has a slowly decaying spectrum)
the error achieved is stated instead, and a warning is logged.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.duhamel import BumpResponse, bump_amplitude_factor, quasi_static_constant
from membrane_models.problems import MembraneForced, StringForced, time_bump
from membrane_models.solution import ExactSolution, FrameFunction
from membrane_models.spectrum import GaussianProfile

__all__ = [
    "MAX_CANDIDATES",
    "MAX_MODES",
    "MAX_TABLE",
    "ForcedModalSolution",
    "forced_modal_solution",
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

    def _basis(self, points: FloatArray, modes: IntArray | None = None) -> FloatArray:
        """phi at ``points`` (n, d) for ``modes`` (default all): shape (n, M)."""
        modes = self.modes if modes is None else modes
        basis = np.ones((points.shape[0], modes.shape[0]))
        for axis in range(self.spatial_dims):
            basis *= np.sin(np.pi * np.outer(points[:, axis], modes[:, axis]))
        return basis

    def at_points(self, points: ArrayLike, t: ArrayLike) -> FloatArray:
        points = self.check_points(points)
        q = self.amplitudes(t)
        out = np.empty((points.shape[0], q.shape[1]))
        block = max(1, _BLOCK_ELEMENTS // max(1, self.n_modes))
        for lo in range(0, points.shape[0], block):
            out[lo : lo + block] = self._basis(points[lo : lo + block]) @ q
        return out

    def on_points(self, points: ArrayLike) -> FrameFunction:
        points = self.check_points(points)
        dynamic_basis = self._basis(points, self.modes[self._dynamic])
        dynamic_basis *= self.coefficients[None, self._dynamic]
        static_field = np.zeros(points.shape[0])
        block = max(1, _BLOCK_ELEMENTS // max(1, points.shape[0]))
        for lo in range(0, self._static.size, block):  # sum_qs F / w^2 phi, in blocks of modes
            part = self._static[lo : lo + block]
            static_field += (
                self._basis(points, self.modes[part]) @ self._static_weights[lo : lo + block]
            )
        response, a = self._response, self.problem.a

        def frame(t: float) -> FloatArray:
            t = float(t)
            values = static_field * float(time_bump(t, a))
            if response is not None:
                values = values + dynamic_basis @ response.at(t)
            return values

        return frame

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


def forced_modal_solution(problem: ForcedProblem, rtol: float = 1e-10) -> ForcedModalSolution:
    """The modal series of a forced problem, truncated at relative error ``rtol``.

    Args:
        problem: a ``StringForced`` or ``MembraneForced``.
        rtol: target bound on sup |truncation error| / max |u| (see the module docstring).
    """
    if not (math.isfinite(rtol) and rtol > 0.0):
        raise ValueError(f"rtol must be a positive number, got {rtol}")
    started = time.perf_counter()
    profiles = _profiles(problem)
    scale = _solution_scale(problem, profiles)
    if scale == 0.0:  # h = 0: nothing moves
        return ForcedModalSolution(problem, np.zeros((0, len(profiles)), np.int64), np.zeros(0), 0)
    budget = rtol * scale
    counts = _candidate_counts(problem, profiles, _OUTSIDE_SHARE * budget)
    outside = _outside_tail(problem, profiles, counts)
    quasi_allowed = _QUASI_STATIC_SHARE * budget
    modes, coefficients, dropped = _select(
        problem, profiles, counts, budget - outside - quasi_allowed
    )
    quasi_static, quasi_error = _quasi_static_modes(problem, modes, coefficients, quasi_allowed)
    modes, coefficients, quasi_static, over_table = _fit_table(
        problem, modes, coefficients, quasi_static
    )
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
        coefficients = np.multiply.outer(coefficients, profile.coefficients(n))
    return np.asarray(coefficients, dtype=np.float64).ravel()


def _mode_bounds(problem: ForcedProblem, modes: IntArray, coefficients: FloatArray) -> FloatArray:
    omega = problem.c * math.pi * np.sqrt((modes.astype(np.float64) ** 2).sum(axis=1))
    return np.abs(coefficients) * bump_amplitude_factor(omega, problem.a)


def _spectral_width(profile: GaussianProfile) -> int:
    """Mode number where the Gaussian spectrum has fallen to ``_FIRST_PASS_SPECTRUM``."""
    return max(
        4, math.ceil(2.0 * math.sqrt(profile.k * math.log(1 / _FIRST_PASS_SPECTRUM)) / math.pi)
    )


def _solution_scale(problem: ForcedProblem, profiles: tuple[GaussianProfile, ...]) -> float:
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

    Returns the kept modes, their coefficients and the sum of the dropped bounds.
    """
    modes = _box_modes(counts)
    coefficients = _box_coefficients(problem, profiles, counts)
    bounds = _mode_bounds(problem, modes, coefficients)
    order = np.argsort(bounds)  # smallest first: the cheapest to drop
    dropped_sums = np.cumsum(bounds[order])
    n_drop = int(np.searchsorted(dropped_sums, max(allowed, 0.0), side="right"))
    n_drop = max(n_drop, len(order) - MAX_MODES)
    dropped = float(dropped_sums[n_drop - 1]) if n_drop else 0.0
    keep = np.sort(order[n_drop:])
    return modes[keep], coefficients[keep], dropped


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
