"""Which modes an engine steps: the mode-count rule.

The modes of the unit string and square with clamped edges are products of sines,
prod sin(m pi x), with angular frequencies w = c pi |m|. An engine keeps

- the modes its lattice resolves: a grid of n points with its end points carries sine modes up
  to n - 2 per axis (higher ones alias onto them), unless a mode count is given;
- for a display-rate step, those the step resolves: w dt <= ``step_limit`` (pi by default: two
  steps per period at most); ``None`` keeps them all, which the exact transition allows at any dt.

The rest are not stepped but keep their static compliance (``static_correction``). The box is
shrunk to the largest kept mode number per axis, so a coarse step on a fine lattice steps a
small box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.errors import InvalidEngineSettings

__all__ = ["MAX_KEPT_MODES", "ModeSet", "choose_modes", "omega_box"]

FloatArray = NDArray[np.float64]
MAX_KEPT_MODES = 2**20  # modes stepped (a few arrays of this size per step)


@dataclass(frozen=True)
class ModeSet:
    """The stepped modes: all of 1 .. box[i] per axis, ``kept`` marks the ones stepped.

    Attributes:
        box: modes per axis of the box.
        omega: angular frequencies on the box.
        kept: mask of the stepped modes on the box.
    """

    box: tuple[int, ...]
    omega: FloatArray
    kept: NDArray[np.bool_]

    @property
    def count(self) -> int:
        return int(self.kept.sum())


def omega_box(c: float, box: tuple[int, ...]) -> FloatArray:
    """w = c pi sqrt(m^2 [+ n^2]) for m = 1 .. box[0] [, n = 1 .. box[1]]: shape ``box``."""
    squares = np.zeros(())
    for count in box:
        squares = np.add.outer(squares, np.arange(1, count + 1, dtype=np.float64) ** 2)
    return np.asarray(c * math.pi * np.sqrt(squares), dtype=np.float64).reshape(box)


def choose_modes(
    c: float,
    lattice: tuple[int, ...],
    dt: float,
    modes: tuple[int, ...] | None,
    step_limit: float | None,
) -> ModeSet:
    """The kept modes for a lattice, a step and the rule's options (module docstring)."""
    counts = tuple(n - 2 for n in lattice) if modes is None else modes
    if math.prod(counts) > MAX_KEPT_MODES:
        raise InvalidEngineSettings(
            f"{'x'.join(map(str, counts))} modes: at most {MAX_KEPT_MODES} are stepped"
        )
    omega = omega_box(c, counts)
    kept = np.ones(counts, dtype=bool) if step_limit is None else omega * dt <= step_limit
    box = tuple(_extent(kept, axis) for axis in range(len(counts)))
    slices = tuple(slice(0, n) for n in box)
    return ModeSet(box, np.ascontiguousarray(omega[slices]), np.ascontiguousarray(kept[slices]))


def _extent(kept: NDArray[np.bool_], axis: int) -> int:
    """1 + the largest index along ``axis`` with a kept mode (0: none)."""
    others = tuple(i for i in range(kept.ndim) if i != axis)
    along = kept.any(axis=others) if others else kept
    hits = np.flatnonzero(along)
    return int(hits[-1]) + 1 if hits.size else 0
