"""Choosing the modes of a forced modal solution: the candidate box, the rigorous bounds on
what is dropped, the quasi-static fast modes and the Duhamel table's size (the method is
described in ``forced``'s docstring).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.budget import check_budget
from membrane_models.exact.duhamel import (
    BumpResponse,
    bump_amplitude_factor,
    bump_integral,
    quasi_static_constant,
)
from membrane_models.exact.spectrum import GaussianProfile, gaussian_sine_integrals
from membrane_models.problems import MembraneForced, StringForced

logger = logging.getLogger(__name__)

logger = logging.getLogger("membrane_models.exact.forced")

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
ForcedProblem = StringForced | MembraneForced
# (problem, modes, coefficients, truncation error, quasi-static mask) -> a solution with .grid
SeriesFactory = Callable[..., Any]

MAX_CANDIDATES = 2**21  # modes in the candidate box (bounds memory: a few arrays of this size)
MAX_MODES = 2**16  # modes kept
MAX_TABLE = 2**23  # entries of the Duhamel table (dynamic modes x panels): 128 MiB
_SAMPLES_PER_AXIS = 33  # first-pass sampling grid for the solution's size U
_SAMPLE_TIMES = 65
_FIRST_PASS_SPECTRUM = 1e-6  # first pass: modes down to this fraction of the Gaussian spectrum
_FIRST_PASS_KEEP = 1e-6  # ... and down to this fraction of the largest mode bound
_IBP = 12.0  # the fast-mode constant of bump_amplitude_factor
_SPECTRUM_BLOCK = 2**16  # mode numbers per block of the closed-form sine integrals


def force_profiles(problem: ForcedProblem) -> tuple[GaussianProfile, ...]:
    if isinstance(problem, MembraneForced):
        return (GaussianProfile(problem.x0, problem.k), GaussianProfile(problem.y0, problem.k))
    return (GaussianProfile(problem.x0, problem.k),)


def series_bytes(problem: ForcedProblem, modes: IntArray, quasi_static: NDArray[np.bool_]) -> int:
    """What a solution with these modes will hold (its ``memory_bytes``), before building it."""
    count, n_static = len(modes), int(quasi_static.sum())
    # modes; coefficients, omega, mask; the dynamic and static index lists; static weights
    held = int(modes.nbytes) + count * (8 + 8 + 1 + 8) + 8 * n_static
    if count > n_static:
        dynamic = modes[~quasi_static].astype(np.float64)
        omega_max = problem.c * math.pi * math.sqrt(float((dynamic**2).sum(axis=1).max()))
        held += BumpResponse.bytes_needed(count - n_static, omega_max, problem.a)
    return held


def check_series(
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
        series_bytes(problem, modes, quasi_static),
        max_bytes,
    )


def left(max_bytes: int | None, used: int) -> int | None:
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


def solution_scale(
    problem: ForcedProblem,
    profiles: tuple[GaussianProfile, ...],
    max_bytes: int | None,
    series: SeriesFactory,
) -> float:
    """U = max |u| on a sampling grid, from a cheap first-pass series (built by ``series``:
    the solution class, which builds on this module)."""
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
    quasi_static, _ = quasi_static_modes(problem, modes, coefficients, allowed)
    # Fast, strong forces (c = 100, k = 1e5) would need gigabytes of table here too; U is an
    # estimate, so the fastest modes go quasi-static (or are left out) beyond MAX_TABLE.
    modes, coefficients, quasi_static, _ = fit_table(problem, modes, coefficients, quasi_static)
    check_series(problem, modes, quasi_static, max_bytes, " of the first pass")
    first = series(problem, modes, coefficients, math.nan, quasi_static)
    axes = [_sample_axis(p.x0) for p in profiles]
    t = np.union1d(np.linspace(0.0, problem.t_end, _SAMPLE_TIMES), [min(0.5, problem.t_end)])
    return float(np.abs(first.grid(*axes, t)).max())


def _sample_axis(centre: float) -> FloatArray:
    return np.union1d(np.linspace(0.0, 1.0, _SAMPLES_PER_AXIS), [centre])


def candidate_counts(
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


def outside_tail(
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


def select(
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


def quasi_static_modes(
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


def fit_table(
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
