"""What a live step needs of a FEM model, tabulated once: modes on the lattice, footprints'
modal forces and the static correction, per footprint radius, on a grid of centres.

A live step cannot afford the mesh (a point probe of scikit-fem costs milliseconds, a sparse
solve 0.2-4 ms), so everything that depends on where a load or probe acts is computed here
on a grid of centres (``interpolation.CentreGrid``, spacing about half the radius) and read
by cubic B-splines at step time:

- the footprint of radius r at centre c is the Gaussian pressure
  g(x) = exp(-|x - c|^2 / r^2) / (pi r^2) (N/m^2 per N; the part beyond the domain presses on
  its support); its load vector f_c = int g v over the mesh, by the element's quadrature;
- its modal forces s_k(c) = phi_k . f_c (N per N; the modes mass-normalised, so the
  footprint-weighted displacement of the stepped modes is s . q, in m);
- the static correction of the modes not stepped: the residual response
  u_res(c) = K^-1 f_c - sum_k phi_k s_k(c) / w_k^2 (one sparse factorisation, a solve per
  centre), its compliance between two footprints r(a, b) = f_b . u_res(a) (m/N) and its field
  on the lattice (m/N).

The lattice is the uniform grid over the domain's bounding box; points outside the domain
carry 0. Units: SI (m, N, s).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import reverse_cuthill_mckee

from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidSolve
from membrane_models.fem.inside import inside_boundary
from membrane_models.fem.interpolation import CentreGrid, prefilter
from membrane_models.fem.modal import Modes
from membrane_models.fem.models import Membrane
from membrane_models.fem.sampling import sampler
from membrane_models.live.tabulated_basis import frozen

__all__ = [
    "MAX_BUILD_BYTES",
    "FootprintTables",
    "LiveTables",
    "footprint_loads",
    "inside_mesh",
    "lattice_points",
    "live_tables",
]

FloatArray = NDArray[np.float64]
# Grid nodes per footprint radius: the modal forces' and fields' grid, and the coarser grid of
# the static correction's compliance (a table over pairs of centres, so its size goes as the
# fourth power). Measured on a 40-mode clamped plate, r = 4 mm, 30 centres: the modal forces
# within 1.3e-4 of their norm, the stepped compliance within 4e-5 and the correction's within
# 2.4e-4 of the whole compliance (benchmarks/fem_figures.py has the skin patch's).
_CENTRES_PER_RADIUS = 3.0
_CROSS_CENTRES_PER_RADIUS = 1.5
# A point force's tables take the grids of a footprint this many elements wide.
_POINT_RADIUS_PER_ELEMENT = 0.75
_CHUNK = 128  # centres per block when building load vectors
# The most the build's largest arrays may take (dense load vectors and solves over the centres,
# the compliance tables): the grids go as (box / radius)^2, so a small radius on a large shape
# would otherwise take all of a machine's memory before failing (1.25 mm on a 100 mm disk:
# an estimated 28 GiB; a build was stopped at 20 GB resident). The study's skin patch: 0.26 GiB.
MAX_BUILD_BYTES = 4 * 2**30
_SOLVE_CHUNK = 1024  # centres per block of static-correction solves


@dataclass(frozen=True, eq=False)
class FootprintTables:
    """One footprint radius's tables, as spline coefficients on ``grid``.

    Attributes:
        radius: r (m).
        grid: the centres.
        modal_force: (nx, ny, modes): s(c).
        own: on ``own_grid``: the static correction's compliance under the footprint,
            r(c, c), or None without a static correction.
        field: (cx, cy, lattice points) on ``cross_grid``: the residual field of a unit force,
            or None without a static correction.
        cross_grid: the coarser grid of the field and of the compliance between two
            footprints (``LiveTables.cross``).
        own_grid: ``cross_grid`` for a footprint; ``grid`` for a point, whose own compliance
            varies on the element's scale.
    """

    radius: float
    grid: CentreGrid
    modal_force: FloatArray
    own: FloatArray | None
    field: FloatArray | None
    cross_grid: CentreGrid
    own_grid: CentreGrid | None = None

    @property
    def nbytes(self) -> int:
        arrays = [self.modal_force, self.own, self.field]
        return sum(int(a.nbytes) for a in arrays if a is not None)


@dataclass(frozen=True, eq=False)
class LiveTables:
    """A FEM model's tables for the live engine.

    Attributes:
        lattice: points per axis of the frames, over ``lower`` .. ``upper`` (m).
        lower, upper: the domain's bounding box (m).
        omega: the modes' angular frequencies (rad/s).
        shapes: the modes on the lattice, (points, modes), 0 outside the domain (m per unit q).
        inside: which lattice points lie in the domain.
        boundary: the mesh's boundary segments, (segments, 2, 2) (m): what ``contains`` tests.
        footprints: the tables of each radius.
        cross: (i, j) -> r(a, b) for a of radius i, b of radius j (i <= j), spline
            coefficients on their ``cross_grid``s (nx_i, ny_i, nx_j, ny_j); empty without a
            static correction.
    """

    lattice: tuple[int, int]
    lower: tuple[float, float]
    upper: tuple[float, float]
    omega: FloatArray
    shapes: FloatArray
    inside: NDArray[np.bool_]
    boundary: FloatArray
    footprints: tuple[FootprintTables, ...]
    cross: dict[tuple[int, int], FloatArray]

    @property
    def nbytes(self) -> int:
        tables = sum(fp.nbytes for fp in self.footprints)
        tables += sum(int(c.nbytes) for c in self.cross.values())
        return tables + int(self.shapes.nbytes + self.omega.nbytes + self.boundary.nbytes)


def lattice_points(
    lower: Sequence[float], upper: Sequence[float], lattice: Sequence[int]
) -> FloatArray:
    """The uniform lattice over the box, x-major: (points, 2) (m)."""
    axes = [np.linspace(lo, hi, n) for lo, hi, n in zip(lower, upper, lattice, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)


def live_tables(
    system: System,
    modes: Modes,
    lattice: tuple[int, int],
    radii: Sequence[float],
    *,
    static_correction: bool = True,
) -> LiveTables:
    """The tables of ``system``'s ``modes`` on ``lattice``, for footprints of ``radii`` (m).

    Raises:
        InvalidSolve: a lattice of fewer than 3 points per axis, or a radius not > 0.
    """
    if len(lattice) != 2 or min(lattice) < 3:
        raise InvalidSolve(f"the lattice needs 2 axes of >= 3 points, got {tuple(lattice)}")
    points = system.domain.mesh.p
    lower = (float(points[0].min()), float(points[1].min()))
    upper = (float(points[0].max()), float(points[1].max()))
    xy = lattice_points(lower, upper, lattice)
    inside = inside_mesh(system, xy)
    shapes = np.zeros((xy.shape[0], modes.count))
    if inside.any():
        shapes[inside] = sampler(system, xy[inside]) @ modes.shapes
    needed = build_bytes(system, modes, lower, upper, xy.shape[0], radii, static_correction)
    if needed > MAX_BUILD_BYTES:
        raise _too_large(needed, radii, lower, upper)
    residual = _Residual(system, modes, xy, inside) if static_correction else None
    built = [_footprint_tables(system, modes, float(r), lower, upper, residual) for r in radii]
    cross = {}
    for i, (_, half_i, weighted_i) in enumerate(built):
        for j in range(i, len(built)):
            _, half_j, weighted_j = built[j]
            if half_i is not None and half_j is not None:
                values = half_i.T @ half_j - weighted_i.T @ weighted_j
                grid_i, grid_j = built[i][0].cross_grid, built[j][0].cross_grid
                cross[(i, j)] = prefilter(
                    values.reshape(*grid_i.shape, *grid_j.shape), (0, 1, 2, 3)
                )
    return LiveTables(
        (int(lattice[0]), int(lattice[1])),
        lower,
        upper,
        frozen(modes.omega.copy()),
        frozen(shapes),
        frozen(inside),
        frozen(boundary_segments(system)),
        tuple(tables for tables, _, _ in built),
        cross,
    )


def footprint_loads(system: System, radius: float, centres: FloatArray) -> FloatArray:
    """Load vectors f_c (N, centres) of unit Gaussian footprints of ``radius`` at ``centres``
    (radius 0: unit point forces, 0 for a centre off the mesh, where it acts on the support)."""
    if radius == 0.0:
        return _point_loads(system, centres)
    basis = system.basis
    x = np.asarray(basis.global_coordinates())  # (2, elements, points)
    qx, qy = x[0].reshape(-1), x[1].reshape(-1)
    weights = _quadrature_matrix(system)
    out = np.empty((system.dofs, centres.shape[0]))
    scale = 1.0 / (math.pi * radius * radius)
    for start in range(0, centres.shape[0], _CHUNK):
        block = centres[start : start + _CHUNK]
        squared = (qx[:, None] - block[None, :, 0]) ** 2 + (qy[:, None] - block[None, :, 1]) ** 2
        out[:, start : start + _CHUNK] = weights @ (scale * np.exp(-squared / radius**2))
    return out


class _Residual:
    """The static correction's solves, with K's banded Cholesky factor K = L L' (K reordered
    by reverse Cuthill-McKee: LAPACK's banded factor and blocked triangular solves take about
    a second for the skin patch's 2,401 centres, where SuperLU's column-at-a-time solves take
    ten).

    r(a, b) = f_a' K^-1 f_b - sum_k s_a,k s_b,k / w_k^2 = (L^-1 f_a) . (L^-1 f_b) - ..., one
    triangular solve per centre and a Gram matrix; the lattice field R f_c = (R P')' f_c with
    R P' solved once for the lattice's points (P samples the lattice).
    """

    def __init__(
        self, system: System, modes: Modes, xy: FloatArray, inside: NDArray[np.bool_]
    ) -> None:
        self.system = system
        self.modes = modes
        self.factor = _BandedCholesky(system.reduced_stiffness)
        lattice = sp.csr_matrix((xy.shape[0], system.dofs))
        if inside.any():
            rows = sp.coo_matrix(sampler(system, xy[inside]))
            index = np.flatnonzero(inside)
            lattice = sp.csr_matrix(
                (rows.data, (index[rows.row], rows.col)), shape=(xy.shape[0], system.dofs)
            )
        # R P' over every DOF, (N, points): the lattice's field per unit load anywhere
        solved = self.factor.solve(system.reduce(lattice.T.toarray()))
        stepped = modes.shapes @ ((lattice @ modes.shapes).T / modes.omega[:, None] ** 2)
        self.lattice_response = system.expand(solved) - stepped

    def half(self, loads: FloatArray) -> FloatArray:
        """L^-1 f for each load column: r(a, b) = half_a . half_b - (s_a / w) . (s_b / w)."""
        return self.factor.half_solve(self.system.reduce(loads))

    def field(self, loads: FloatArray) -> FloatArray:
        """The residual field on the lattice of each load column (points, centres)."""
        return np.asarray(self.lattice_response.T @ loads)


class _BandedCholesky:
    """K = L L' for a sparse symmetric positive definite K, reordered to a narrow band."""

    def __init__(self, matrix: sp.spmatrix) -> None:
        csr = sp.csr_matrix(matrix)
        self.order = reverse_cuthill_mckee(csr, symmetric_mode=True)
        permuted = sp.coo_matrix(csr[self.order][:, self.order])
        lower = permuted.row >= permuted.col
        offsets = (permuted.row - permuted.col)[lower]
        band = np.zeros((int(offsets.max(initial=0)) + 1, csr.shape[0]))
        band[offsets, permuted.col[lower]] = permuted.data[lower]
        try:
            self.band = scipy.linalg.cholesky_banded(band, lower=True)
        except np.linalg.LinAlgError:
            raise InvalidSolve(
                "the stiffness is not positive definite: is the model held?"
            ) from None

    def half_solve(self, rhs: FloatArray) -> FloatArray:
        """L^-1 rhs (rows in K's order)."""
        solved, info = scipy.linalg.lapack.dtbtrs(self.band, rhs[self.order], uplo="L")
        if info != 0:
            raise InvalidSolve(f"the banded triangular solve failed (LAPACK info {info})")
        return np.asarray(solved)

    def solve(self, rhs: FloatArray) -> FloatArray:
        """K^-1 rhs."""
        solved = scipy.linalg.cho_solve_banded((self.band, True), rhs[self.order])
        out = np.empty_like(solved)
        out[self.order] = solved
        return out


def _footprint_tables(
    system: System,
    modes: Modes,
    radius: float,
    lower: tuple[float, float],
    upper: tuple[float, float],
    residual: _Residual | None,
) -> tuple[FootprintTables, FloatArray | None, FloatArray]:
    """One radius's tables, with its centres' half solves L^-1 f_c and s_c / w (the cross
    tables' factors; None without a static correction)."""
    if not (math.isfinite(radius) and radius >= 0.0):
        raise InvalidSolve(f"a footprint radius must be >= 0 m, got {radius!r}")
    if radius == 0.0 and isinstance(system.model, Membrane):
        raise InvalidSolve(
            "a point force on a membrane has an infinite displacement under it (logarithmic): "
            "give a footprint radius > 0"
        )
    grid, cross_grid = _centre_grids(system, radius, lower, upper)
    loads = footprint_loads(system, radius, grid.nodes())
    forces = modes.shapes.T @ loads  # (modes, centres)
    nx, ny = grid.shape
    modal_force = prefilter(forces.T.reshape(nx, ny, -1), (0, 1))
    if residual is None:
        tables = FootprintTables(radius, grid, modal_force, None, None, cross_grid)
        return tables, None, forces
    coarse = footprint_loads(system, radius, cross_grid.nodes())
    cx, cy = cross_grid.shape
    field = prefilter(residual.field(coarse).T.reshape(cx, cy, -1), (0, 1))
    half = residual.half(coarse)
    weighted = (modes.shapes.T @ coarse) / modes.omega[:, None]
    if radius > 0.0:  # a footprint's own compliance is as smooth as the cross one: same grid
        own_grid, own = cross_grid, _own(half, weighted)
    else:  # a point's varies on the element's scale: the finer grid, solved in blocks
        own_grid, own = grid, _point_own(residual, loads, forces / modes.omega[:, None])
    own_table = prefilter(own.reshape(own_grid.shape), (0, 1))
    tables = FootprintTables(radius, grid, modal_force, own_table, field, cross_grid, own_grid)
    return tables, half, weighted


def _centre_grids(
    system: System, radius: float, lower: tuple[float, float], upper: tuple[float, float]
) -> tuple[CentreGrid, CentreGrid]:
    """A radius's grid of centres (modal forces, fields) and its coarser one (compliance)."""
    # A point's tables follow the mesh (its modes' values vary on the element's scale).
    scale = radius if radius > 0.0 else system.domain.size * _POINT_RADIUS_PER_ELEMENT
    grid = CentreGrid.covering(lower, upper, scale / _CENTRES_PER_RADIUS)
    return grid, CentreGrid.covering(lower, upper, scale / _CROSS_CENTRES_PER_RADIUS)


def build_bytes(
    system: System,
    modes: Modes,
    lower: tuple[float, float],
    upper: tuple[float, float],
    points: int,
    radii: Sequence[float],
    static_correction: bool = True,
) -> int:
    """About what the build's largest arrays take at once (bytes): per radius, the load vectors
    over its centres (DOFs x centres, and twice over the coarser centres with the correction:
    loads and half solves) and its field on the lattice; the compliance tables over pairs."""
    total, cross_sizes = 0, []
    for radius in radii:
        if not (math.isfinite(radius) and radius >= 0.0):
            continue  # refused with its reason by _footprint_tables
        grid, cross_grid = _centre_grids(system, radius, lower, upper)
        fine = math.prod(grid.shape)
        total += system.dofs * fine + modes.count * fine
        if static_correction:
            coarse = math.prod(cross_grid.shape)
            total += 2 * system.dofs * coarse + points * coarse
            cross_sizes.append(coarse)
    pairs = sum(a * b for i, a in enumerate(cross_sizes) for b in cross_sizes[i:])
    return 8 * (total + 2 * pairs + system.dofs * points)


def _too_large(
    needed: int, radii: Sequence[float], lower: tuple[float, float], upper: tuple[float, float]
) -> InvalidSolve:
    sizes = ", ".join(f"{r * 1e3:.6g} mm" if r > 0.0 else "points" for r in radii)
    return InvalidSolve(
        f"these live tables would take about {needed / 2**30:.1f} GiB to build (at most "
        f"{MAX_BUILD_BYTES / 2**30:.0f} GiB): footprints of {sizes} are small for a domain "
        f"of {(upper[0] - lower[0]) * 1e3:.6g} x {(upper[1] - lower[1]) * 1e3:.6g} mm "
        "(their tables' centres go as (size / radius)^2): give larger radii, a smaller "
        "domain or a coarser mesh"
    )


def _own(half: FloatArray, weighted: FloatArray) -> FloatArray:
    """r(c, c) per column: |L^-1 f_c|^2 - |s_c / w|^2."""
    return np.asarray(np.einsum("ij,ij->j", half, half) - np.einsum("ij,ij->j", weighted, weighted))


def _point_own(residual: _Residual, loads: FloatArray, weighted: FloatArray) -> FloatArray:
    own = np.empty(loads.shape[1])
    for start in range(0, loads.shape[1], _SOLVE_CHUNK):  # bounded memory: N x chunk at most
        block = slice(start, start + _SOLVE_CHUNK)
        own[block] = _own(residual.half(loads[:, block]), weighted[:, block])
    return own


def _point_loads(system: System, centres: FloatArray) -> FloatArray:
    """Unit point forces at ``centres`` (N, centres): the basis evaluated there; 0 off the mesh."""
    out = np.zeros((system.dofs, centres.shape[0]))
    inside = inside_mesh(system, centres)
    if inside.any():
        out[:, inside] = sampler(system, centres[inside]).T.toarray()
    return out


def _quadrature_matrix(system: System) -> sp.csr_matrix:
    """B (N, quadrature points): B[i, q] = dx_q v_i(x_q), so that B g(x_q) = int g v_i."""
    basis = system.basis
    elements, per_element = basis.dx.shape
    columns = np.arange(elements * per_element).reshape(elements, per_element)
    rows, cols, values = [], [], []
    for k in range(basis.Nbfun):
        value = np.asarray(basis.basis[k][0]) * basis.dx
        rows.append(np.repeat(basis.element_dofs[k][:, None], per_element, axis=1).reshape(-1))
        cols.append(columns.reshape(-1))
        values.append(value.reshape(-1))
    return sp.csr_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
        shape=(system.dofs, elements * per_element),
    )


def boundary_segments(system: System) -> FloatArray:
    """The mesh's boundary edges as segments (segments, 2, 2) (m)."""
    mesh = system.domain.mesh
    facets = mesh.facets[:, mesh.boundary_facets()]
    return np.ascontiguousarray(np.transpose(mesh.p[:, facets], (2, 1, 0)))


def inside_mesh(system: System, xy: FloatArray) -> NDArray[np.bool_]:
    """Which points lie on the mesh (points on its boundary count)."""
    extent = float(np.ptp(system.domain.mesh.p, axis=1).max())
    return inside_boundary(xy, boundary_segments(system), 1e-12 * extent)
