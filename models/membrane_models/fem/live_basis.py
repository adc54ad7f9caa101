"""FEM modes as a live basis: the stepping core steps them exactly as it steps sine modes.

``fem_basis(tables)`` is a ``live.tabulated_basis.TabulatedBasis`` over a model's
``tables.LiveTables``: the modes on the lattice, the footprints' modal forces and the static
correction read from the tables by cubic B-splines (``interpolation``), so a step costs table
reads, never a solve. Loads, probes, damping, initial shapes and the static correction are the
core's; this module only answers where a footprint is and what it weighs.

Units: SI. A load's ``force`` is in N (> 0 along +w), a probe's ``depth`` in m, centres and
radii in m; frames and probe displacements in m, compliances in m/N. A footprint is the
Gaussian pressure of ``tables`` and its radius must be one the tables were built for (a
table per radius: the tool's and the loads' radii are the scene's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.fem.inside import inside_boundary
from membrane_models.fem.interpolation import CentreGrid
from membrane_models.fem.tables import LiveTables
from membrane_models.live.tabulated_basis import TableFootprint, TabulatedBasis

__all__ = ["FemCorrection", "FemFootprints", "fem_basis"]

FloatArray = NDArray[np.float64]
_RADIUS_MATCH = 1e-9  # relative: a radius given in mm and converted is still the table's


class FemFootprints:
    """Footprints on a FEM model (``tabulated_basis.FootprintModel``)."""

    def __init__(self, tables: LiveTables) -> None:
        self.tables = tables
        extent = max(b - a for a, b in zip(tables.lower, tables.upper, strict=True))
        self._on_edge = 1e-12 * extent
        self._rectangular = _fills_its_box(tables.boundary, tables.lower, tables.upper)
        self._radii = tuple(fp.radius for fp in tables.footprints)

    @property
    def radii(self) -> tuple[float, ...]:
        return self._radii

    def index(self, radius: float) -> int | None:
        """Which radius's tables carry ``radius`` (None: none)."""
        radii = self._radii
        if radius in radii:  # the usual case, and the fast one (a step asks a few times)
            return radii.index(radius)
        for i, known in enumerate(radii):
            if math.isclose(radius, known, rel_tol=_RADIUS_MATCH):
                return i
        return None

    def refuses(self, radius: float) -> str | None:
        if self.index(radius) is not None:
            return None
        known = ", ".join(f"{r * 1e3:.6g} mm" if r > 0 else "points (0)" for r in self.radii)
        return f"radius {radius:.6g} m: this tissue's tables carry footprints of {known} only"

    def contains(self, at: tuple[float, ...]) -> bool:
        """Inside the mesh's boundary, or on it (``inside.inside_boundary``)."""
        lower, upper = self.tables.lower, self.tables.upper
        if not (lower[0] <= at[0] <= upper[0] and lower[1] <= at[1] <= upper[1]):
            return False
        if self._rectangular:  # the box is the domain: nothing more to test
            return True
        point = np.array([at], dtype=np.float64)
        return bool(inside_boundary(point, self.tables.boundary, self._on_edge)[0])

    def modal_force(self, at: tuple[float, ...], radius: float) -> FloatArray:
        tables = self.tables.footprints[self._known(radius)]
        return tables.grid.read(tables.modal_force, at)

    def _known(self, radius: float) -> int:
        index = self.index(radius)
        if index is None:
            raise ValueError(self.refuses(radius))  # refused before, by the basis
        return index


class FemCorrection:
    """The static correction of the modes not stepped (``tabulated_basis.StaticCorrection``)."""

    def __init__(self, footprints: FemFootprints) -> None:
        self.footprints = footprints
        self.tables = footprints.tables

    def compliance(self, a: TableFootprint, b: TableFootprint) -> float:
        i, j = self.footprints._known(a.radius), self.footprints._known(b.radius)
        if i == j and a.at == b.at:  # a footprint's own: the finer diagonal table
            tables = self.tables.footprints[i]
            assert tables.own is not None and tables.own_grid is not None  # with a correction
            return float(tables.own_grid.read(tables.own, a.at))
        if i > j:
            a, b, i, j = b, a, j, i
        grid_a = self.tables.footprints[i].cross_grid
        grid_b = self.tables.footprints[j].cross_grid
        return _read_pair(self.tables.cross[(i, j)], grid_a, grid_b, a.at, b.at)

    def field(self, footprint: TableFootprint) -> FloatArray:
        tables = self.tables.footprints[self.footprints._known(footprint.radius)]
        assert tables.field is not None  # a correction exists only with its fields
        return tables.cross_grid.read(tables.field, footprint.at)


def fem_basis(
    tables: LiveTables,
    *,
    kept: ArrayLike | None = None,
    static_correction: bool = True,
) -> TabulatedBasis:
    """The live basis of a FEM model's tables (``kept``: the modes stepped, default all).

    ``static_correction`` needs tables built with it.
    """
    footprints = FemFootprints(tables)
    corrected = static_correction and bool(tables.cross)
    return TabulatedBasis(
        tables.lattice,
        tables.shapes,
        tables.omega,
        footprints,
        kept=kept,
        correction=FemCorrection(footprints) if corrected else None,
        description={
            "basis": "fem",
            "units": "SI",
            "radii": list(footprints.radii),
            "lower": list(tables.lower),
            "upper": list(tables.upper),
            "table_bytes": tables.nbytes,
        },
        held_bytes=tables.nbytes,
    )


def _read_pair(
    coefficients: FloatArray,
    grid_a: CentreGrid,
    grid_b: CentreGrid,
    a: Sequence[float],
    b: Sequence[float],
) -> float:
    """A table over two centres' grids at (a, b): 16 x 16 nodes and their spline weights."""
    ax, ay, wa = grid_a.stencil(a)
    bx, by, wb = grid_b.stencil(b)
    return float(wa @ coefficients[ax, ay, bx, by].reshape(16, 16) @ wb)


def _fills_its_box(
    segments: FloatArray, lower: tuple[float, float], upper: tuple[float, float]
) -> bool:
    """Whether every boundary segment lies on the bounding box (a rectangle without holes)."""
    x, y = segments[:, :, 0], segments[:, :, 1]
    tol = 1e-12 * max(upper[0] - lower[0], upper[1] - lower[1])
    on_x = (np.abs(x - lower[0]) <= tol) | (np.abs(x - upper[0]) <= tol)
    on_y = (np.abs(y - lower[1]) <= tol) | (np.abs(y - upper[1]) <= tol)
    vertical = on_x.all(axis=1) & (np.abs(x[:, 0] - x[:, 1]) <= tol)
    horizontal = on_y.all(axis=1) & (np.abs(y[:, 0] - y[:, 1]) <= tol)
    return bool((vertical | horizontal).all())
