"""Tables on a uniform grid of centres, read anywhere between its nodes by cubic B-splines.

What a live step needs of the FEM model at a load's or a probe's centre (its modal forces, the
static correction's compliance and field) is computed at build time on a grid of centres and
read at step time from the spline coefficients: 4 nodes per axis, error O(h^4) for a smooth
function. The coefficients come from scipy's B-spline prefilter (``scipy.ndimage``), along the
grid's axes only (a table may carry trailing value axes, or a second pair of grid axes for a
function of two centres). The grid reaches ``MARGIN`` nodes past the region queries come from,
so that the prefilter's boundary rule never weighs on a value read inside it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.ndimage
from numpy.typing import NDArray

__all__ = ["MARGIN", "CentreGrid", "prefilter"]

FloatArray = NDArray[np.float64]
MARGIN = 4  # nodes past the queried region on every side


@dataclass(frozen=True)
class CentreGrid:
    """Nodes origin + (i, j) * spacing, i < shape[0], j < shape[1] (m)."""

    origin: tuple[float, float]
    spacing: float
    shape: tuple[int, int]

    @classmethod
    def covering(cls, lower: Sequence[float], upper: Sequence[float], spacing: float) -> CentreGrid:
        """The grid of ``spacing`` covering the box [lower, upper] with ``MARGIN`` nodes more
        on every side."""
        counts = tuple(
            math.ceil((hi - lo) / spacing - 1e-9) + 1 + 2 * MARGIN
            for lo, hi in zip(lower, upper, strict=True)
        )
        origin = (lower[0] - MARGIN * spacing, lower[1] - MARGIN * spacing)
        return cls(origin, float(spacing), (int(counts[0]), int(counts[1])))

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    def nodes(self) -> FloatArray:
        """Every node's (x, y), x-major: shape (size, 2)."""
        x = self.origin[0] + self.spacing * np.arange(self.shape[0])
        y = self.origin[1] + self.spacing * np.arange(self.shape[1])
        return np.stack(np.meshgrid(x, y, indexing="ij"), axis=-1).reshape(-1, 2)

    def stencil(self, at: Sequence[float]) -> tuple[slice, slice, FloatArray]:
        """The 4 x 4 nodes around ``at`` and their cubic B-spline weights, (16,) x-major."""
        ix, wx = self._axis(at[0], 0)
        iy, wy = self._axis(at[1], 1)
        weights = np.array([a * b for a in wx for b in wy])
        return slice(ix - 1, ix + 3), slice(iy - 1, iy + 3), weights

    def read(self, coefficients: FloatArray, at: Sequence[float]) -> FloatArray:
        """The interpolated value at ``at`` of a table whose first two axes are the grid's."""
        ix, wx = self._axis(at[0], 0)
        iy, wy = self._axis(at[1], 1)
        block = coefficients[ix - 1 : ix + 3, iy - 1 : iy + 3]
        # separable: the x weights, then the y weights (two small products, no 16-row copy)
        along_x = np.array(wx) @ block.reshape(4, -1)
        return np.asarray(np.array(wy) @ along_x.reshape(4, -1)).reshape(block.shape[2:])

    def read_pair(self, coefficients: FloatArray, a: Sequence[float], b: Sequence[float]) -> float:
        """The interpolated value at (a, b) of a table over two centres, (nx, ny, nx, ny)."""
        ax, ay, wa = self.stencil(a)
        bx, by, wb = self.stencil(b)
        block = coefficients[ax, ay, bx, by].reshape(16, 16)
        return float(wa @ block @ wb)

    def _axis(self, value: float, axis: int) -> tuple[int, tuple[float, float, float, float]]:
        # plain floats: a step reads a few tables, and numpy's call overhead would dominate
        u = (value - self.origin[axis]) / self.spacing
        base = min(max(math.floor(u), 1), self.shape[axis] - 3)
        t = u - base
        s = 1.0 - t
        t2 = t * t
        t3 = t2 * t
        sixth = 1.0 / 6.0
        return base, (
            s * s * s * sixth,
            (3.0 * t3 - 6.0 * t2 + 4.0) * sixth,
            (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) * sixth,
            t3 * sixth,
        )


def prefilter(values: FloatArray, axes: Sequence[int]) -> FloatArray:
    """Cubic B-spline coefficients of ``values`` along ``axes`` (the grid's), read-only."""
    out = np.asarray(values, dtype=np.float64)
    for axis in axes:
        out = scipy.ndimage.spline_filter1d(out, order=3, axis=axis, mode="mirror")
    out.setflags(write=False)
    return out
