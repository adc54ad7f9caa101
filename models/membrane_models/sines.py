"""The sine-sum kernel: sum_k a_k s_k prod sin(m_k pi x) at fixed points, in the form that fits.

``sine_sum`` chooses ``dense`` (a cached points x modes basis), ``grid`` (modes folded onto the
uniform lattice x_i = i / N and one type-I discrete sine transform) or ``chunked`` (the basis
recomputed block by block), within a memory budget; the exact solutions use it for frames on a
scene's points.
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from membrane_models.budget import MemoryBudgetExceeded

__all__ = [
    "ChunkedSineSum",
    "DenseSineSum",
    "GridSineSum",
    "SineSum",
    "axis_sines",
    "fold_axis",
    "lattice_sines",
    "sine_basis",
    "sine_sum",
    "uniform_grid_shape",
]

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_DENSE_PREFERRED_BYTES = 32 * 2**20  # a dense basis this small is the fastest form per frame
_CHUNK_ELEMENTS = 2**19  # float64 elements of basis per block when recomputed per frame (4 MiB)
_MAX_CHUNKED_SINES = 2**24  # sines per frame beyond which recomputing is too slow (~0.4 s)
_GRID_TOLERANCE = 1e-15  # points this close to i / N are the uniform grid (linspace rounding)


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
            sine_basis(points[lo : lo + rows], modes, block, _rows(scratch, len(block)))
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
            basis = sine_basis(rows, self._modes, block[: len(rows)], _rows(scratch, len(rows)))
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


def sine_basis(
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


def axis_sines(x: FloatArray, count: int) -> FloatArray:
    """sin(m pi x) for m = 1 .. count: shape (len(x), count), the bits of ``sine_basis``."""
    out = np.empty((x.size, count))
    _axis_sines(x, np.arange(1, count + 1), out)
    return out


def lattice_sines(points: int, count: int) -> FloatArray:
    """sin(m pi i / N) on the uniform lattice i = 0 .. N (N = points - 1), m = 1 .. count,
    with the clamped end rows exactly 0: shape (points, count)."""
    table = axis_sines(np.arange(points, dtype=np.float64) / (points - 1), count)
    table[[0, -1]] = 0.0
    return table


def fold_axis(z: FloatArray, axis: int, intervals: int) -> FloatArray:
    """Coefficients of modes 1 .. M along ``axis`` folded onto the modes 1 .. N - 1 a lattice
    of N intervals resolves: sin(m pi i / N) is 2N-periodic and odd about N in m, so mode m
    adds to j = m mod 2N with sign +, or to 2N - j with sign - (``_fold_modes``'s rule, for a
    dense box of coefficients)."""
    period = 2 * intervals
    moved = np.moveaxis(z, axis, 0)
    count = moved.shape[0]
    length = period * math.ceil((count + 1) / period)
    padded = np.zeros((length, *moved.shape[1:]))
    padded[1 : count + 1] = moved  # row m holds mode m (row 0: mode 0, nothing)
    sums = padded.reshape(length // period, period, *moved.shape[1:]).sum(axis=0)
    folded = sums[1:intervals] - sums[period - 1 : intervals : -1]  # m = j and m = 2N - j
    return np.moveaxis(folded, 0, axis)


def _axis_sines(x: FloatArray, m: IntArray, out: FloatArray) -> None:
    np.multiply.outer(x, m, out=out)
    np.multiply(np.pi, out, out=out)
    np.sin(out, out=out)
