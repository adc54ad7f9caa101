"""The lowest modes: K phi = omega^2 M phi on the constrained space.

``modes(system, count)`` finds the ``count`` lowest eigenpairs with scipy's ``eigsh`` in
shift-invert mode about ``shift`` (0 by default: below the first eigenvalue, since
``assemble`` refuses rigid-body modes, so K_r is positive definite and its factorisation is
the one ARPACK needs); a small system (or a count near its size) is solved dense. The shapes
come back on every DOF (``T phi_r``), mass-normalised (phi' M phi = 1, so modal masses are 1
and phi' K phi = omega^2), sorted by omega (rad/s) and signed so that each one's largest
vertex deflection is positive.

ARPACK starts from a fixed vector (``_START_SEED``): left to itself it draws one from a random
state that lives as long as the process, so a degenerate pair (a disk's, a square's) came out
rotated differently depending on what the process had solved before, and a table built in one
process differed from the same table built in another.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from scipy.sparse.linalg import eigsh

from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidSolve

__all__ = ["Modes", "modes"]

FloatArray = NDArray[np.float64]
_DENSE = 600  # a constrained space this small is solved dense
_START_SEED = 0  # ARPACK's starting vector: drawn from this seed, the same in every process


@dataclass(frozen=True, eq=False)
class Modes:
    """The lowest modes of a system.

    Attributes:
        omega: angular frequencies ``(k,)``, rad/s, ascending.
        shapes: ``(N, k)`` DOF vectors, mass-normalised.
    """

    omega: FloatArray
    shapes: FloatArray

    @property
    def count(self) -> int:
        return int(self.omega.size)

    @property
    def frequency(self) -> FloatArray:
        """omega / (2 pi), Hz."""
        return np.asarray(self.omega / (2 * math.pi), dtype=np.float64)


def modes(system: System, count: int, shift: float = 0.0) -> Modes:
    """The ``count`` lowest modes (module docstring)."""
    n = system.free
    if isinstance(count, bool) or not isinstance(count, numbers.Integral) or count < 1:
        raise InvalidSolve(f"a mode count is a positive integer, not {count!r}")
    if count > n:
        raise InvalidSolve(f"{count} modes asked of a system with {n} free DOFs")
    if not math.isfinite(shift):
        raise InvalidSolve(f"the shift must be finite, not {shift!r}")
    k, m = system.reduced_stiffness, system.reduced_mass
    if n <= _DENSE or count >= n - 1:
        values, vectors = scipy.linalg.eigh(
            k.toarray(), m.toarray(), subset_by_index=[0, count - 1]
        )
    else:
        start = np.random.default_rng(_START_SEED).standard_normal(n)
        values, vectors = eigsh(k, k=int(count), M=m, sigma=shift, which="LM", v0=start)
    order = np.argsort(values)
    values, vectors = values[order], vectors[:, order]
    vectors = vectors / np.sqrt(np.einsum("ik,ik->k", vectors, m @ vectors))
    shapes = system.expand(vectors)
    vertex = system.vertex_values(shapes)
    peak = vertex[np.argmax(np.abs(vertex), axis=0), np.arange(count)]
    shapes = shapes * np.where(peak < 0, -1.0, 1.0)
    omega = np.sqrt(np.clip(values, 0.0, None))
    return Modes(np.asarray(omega, dtype=np.float64), np.asarray(shapes, dtype=np.float64))
