"""Frames from modal coefficients on the uniform lattice x_i = i / N (i = 0 .. N), per axis.

The value at the lattice of sum_m Z_m prod sin(m pi x) is a product of per-axis sine tables
T[i, m] = sin(m pi i / N) with the coefficients: T z (string), T_x Z T_y^T (membrane), two
small matrix products for a separable box. Coefficients beyond the tables (a static correction
reaching thousands of modes) are folded first: sin(m pi i / N) is 2N-periodic and odd about N in
m, so mode m adds, with a sign, to one of 1 .. N - 1 (the modes the lattice resolves). The
tables and the fold are the shared sine kernel's (``membrane_models.sines``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from membrane_models.sines import fold_axis, lattice_sines

__all__ = ["DENSE_TABLE_ELEMENTS", "LatticeSynthesis"]

FloatArray = NDArray[np.float64]

DENSE_TABLE_ELEMENTS = 2**20  # a sine table up to this size (8 MiB) per axis; beyond, fold


class LatticeSynthesis:
    """Sine tables of a lattice, grown on demand, and the frames they give.

    Args:
        shape: points per axis (each >= 3), the end points included.
    """

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.shape = shape
        self._intervals = tuple(n - 1 for n in shape)
        self._tables = [self._table(axis, n - 2) for axis, n in enumerate(shape)]

    @property
    def nbytes(self) -> int:
        return sum(int(t.nbytes) for t in self._tables)

    def sines(self, axis: int, count: int) -> FloatArray:
        """T (points, count) along ``axis``: a view of the table (grown when needed)."""
        table = self._tables[axis]
        if table.shape[1] < count:
            grown = max(count, 2 * table.shape[1])
            table = self._tables[axis] = self._table(axis, grown)
        return table[:, :count]

    def resolved(self, axis: int) -> FloatArray:
        """T for the modes 1 .. N - 1 the lattice resolves along ``axis``."""
        return self.sines(axis, self._intervals[axis] - 1)

    def frame(self, coefficients: FloatArray) -> FloatArray:
        """sum_m Z_m phi_m at the lattice, x-major and flattened: shape (points,)."""
        z = coefficients
        factors = []
        for axis in range(z.ndim):
            count = z.shape[axis]
            if self.shape[axis] * count <= DENSE_TABLE_ELEMENTS:
                factors.append(self.sines(axis, count))
            else:
                z = self._fold(z, axis)
                factors.append(self.resolved(axis))
        if z.ndim == 1:
            return np.asarray(factors[0] @ z)
        return np.asarray((factors[0] @ z @ factors[1].T).reshape(-1))

    def _table(self, axis: int, count: int) -> FloatArray:
        return lattice_sines(self.shape[axis], count)

    def _fold(self, z: FloatArray, axis: int) -> FloatArray:
        """Coefficients of modes 1 .. M folded onto 1 .. N - 1 along ``axis``."""
        return fold_axis(z, axis, self._intervals[axis])
