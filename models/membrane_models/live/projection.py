"""Initial shapes given on the lattice, projected on the stepped modes by least squares.

On the uniform lattice x_i = i / N the sampled sines of modes 1 .. N - 1 are orthogonal,
sum_i sin(m pi i / N) sin(n pi i / N) = (N / 2) delta_mn, so the least-squares coefficients of
any subset of them are the discrete sine coefficients (2 / N)^d T^T U restricted to it. Modes
beyond N - 1 alias onto those and get none (the minimum-norm answer). What the modes cannot
carry (values on the clamped edges, detail finer than the kept modes) is the residual,
||U - projected|| / ||U||, reported so that a shape the engine cannot hold is visible.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.errors import InvalidShape
from membrane_models.live.modes import ModeSet
from membrane_models.live.synthesis import LatticeSynthesis

__all__ = ["MAX_SHAPE_VALUE", "checked_shape", "project"]

MAX_SHAPE_VALUE = 1e3  # the largest |value| of an initial displacement or velocity

FloatArray = NDArray[np.float64]


def project(
    shape: ArrayLike, modes: ModeSet, synthesis: LatticeSynthesis, what: str
) -> tuple[FloatArray, float]:
    """Coefficients on the mode box (0 off the kept modes) and the relative residual.

    Args:
        shape: values on the lattice, shaped like it or flattened x-major.
        modes: the kept modes.
        synthesis: the lattice's sine tables.
        what: "displacement" or "velocity", for messages.

    Raises:
        InvalidShape: wrong size, or not finite.
    """
    lattice = synthesis.shape
    values = checked_shape(shape, lattice, what).reshape(lattice)
    coefficients = values
    for axis, n in enumerate(lattice):
        table = synthesis.resolved(axis) * (2.0 / (n - 1))
        coefficients = np.moveaxis(np.tensordot(table.T, coefficients, axes=([1], [axis])), 0, axis)
    box = np.zeros(modes.box)
    common = tuple(slice(0, min(k, c)) for k, c in zip(modes.box, coefficients.shape, strict=True))
    box[common] = coefficients[common]
    box *= modes.kept
    norm = float(np.linalg.norm(values))
    if norm == 0.0:
        return box, 0.0
    residual = float(np.linalg.norm(values.reshape(-1) - synthesis.frame(box))) / norm
    return box, residual


def checked_shape(shape: ArrayLike, lattice: tuple[int, ...], what: str) -> FloatArray:
    """``shape`` as a flat float array of the lattice's size, finite and within range.

    Raises:
        InvalidShape: wrong size, not numbers, not finite, or beyond ``MAX_SHAPE_VALUE``.
    """
    try:
        values = np.asarray(shape, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidShape(f"the initial {what} must be an array of numbers") from None
    if values.size != math.prod(lattice):
        raise InvalidShape(
            f"the initial {what} needs {math.prod(lattice)} values (lattice "
            f"{'x'.join(map(str, lattice))}), got {values.size}"
        )
    if not np.all(np.isfinite(values)):
        raise InvalidShape(f"the initial {what} must be finite (it holds NaN or inf)")
    if values.size and float(np.max(np.abs(values))) > MAX_SHAPE_VALUE:
        raise InvalidShape(
            f"the initial {what} must stay within +-{MAX_SHAPE_VALUE:g} problem units "
            "(the linear model's range; a larger value would overflow its sums)"
        )
    return values.reshape(-1)
