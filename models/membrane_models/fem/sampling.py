"""A FEM field's values (and derivatives) at arbitrary points: the build-time reader.

``sample(system, u, points)`` evaluates w (m) at points ``(n, 2)`` (m): each point is located
in its triangle, mapped back to the reference triangle, and the element's basis functions are
evaluated there (what scikit-fem's ``probes`` does, here also on the membrane's curved
triangles, which scikit-fem cannot locate in: a point between a rim chord and the arc is
found by inverting the curved map). ``sampler`` is that evaluation as a sparse matrix
``(n, N)``, which the live path tabulates once; ``derivatives`` adds the gradient and the
Hessian (the plate's curvatures, for ``stress``). A point off the mesh is an
``OutsideDomain``. Morley's field is continuous only at the vertices: sampling it is refused
(``System.vertex_values`` reads the vertices), though a point load on it is exact.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidSolve, OutsideDomain

__all__ = ["derivatives", "evaluation", "locate", "sample", "sampler"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
_INSIDE = 1e-10  # reference-coordinate slack of "inside a triangle"


def sampler(system: System, points: ArrayLike) -> sp.csr_matrix:
    """The matrix ``S`` ``(n, N)`` with ``S @ u`` = w at ``points`` ``(n, 2)``."""
    _sampled(system)
    return evaluation(system, _points(points))


def sample(system: System, u: ArrayLike, points: ArrayLike) -> FloatArray:
    """w (m) at ``points`` ``(n, 2)`` (or one ``(x, y)``): shape ``(n,)`` (``()``), with a
    trailing axis for each column of ``u`` ``(N, k)``."""
    single = np.ndim(points) == 1
    values = np.asarray(sampler(system, points) @ np.asarray(u, dtype=np.float64))
    return np.asarray(values[0] if single else values, dtype=np.float64)


def derivatives(
    system: System, u: ArrayLike, points: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """w ``(n,)`` (m), grad w ``(n, 2)`` and the Hessian ``(n, 2, 2)`` (1/m) at ``points``."""
    _sampled(system)
    xy = _points(points)
    basis = system.basis
    cells, local = locate(system, xy)
    coefficients = np.asarray(u, dtype=np.float64)[basis.element_dofs[:, cells]]  # (Nbfun, n)
    value = np.zeros(xy.shape[0])
    gradient = np.zeros((xy.shape[0], 2))
    hessian = np.zeros((xy.shape[0], 2, 2))
    for k in range(basis.Nbfun):
        field: Any = basis.elem.gbasis(basis.mapping, local, k, tind=cells)[0]
        value += coefficients[k] * np.asarray(field)[:, 0]
        gradient += coefficients[k][:, None] * field.grad[:, :, 0].T
        if field.hess is not None:
            hessian += coefficients[k][:, None, None] * np.moveaxis(field.hess[:, :, :, 0], -1, 0)
    return value, gradient, hessian


def evaluation(system: System, xy: FloatArray) -> sp.csr_matrix:
    """The basis functions' values at points ``(n, 2)``: ``(n, N)``, any element."""
    basis = system.basis
    cells, local = locate(system, xy)
    values = np.array(
        [
            np.asarray(basis.elem.gbasis(basis.mapping, local, k, tind=cells)[0])[:, 0]
            for k in range(basis.Nbfun)
        ]
    )  # (Nbfun, n)
    rows = np.broadcast_to(np.arange(xy.shape[0]), values.shape)
    matrix = sp.coo_matrix(
        (values.ravel(), (rows.ravel(), basis.element_dofs[:, cells].ravel())),
        shape=(xy.shape[0], basis.N),
    )
    return sp.csr_matrix(matrix)


def locate(system: System, xy: FloatArray) -> tuple[IntArray, FloatArray]:
    """Each point's triangle ``(n,)`` and reference coordinates ``(2, n, 1)``."""
    mesh = system.domain.mesh
    finder = mesh.element_finder()
    cells = np.full(xy.shape[0], -1, dtype=np.int64)
    try:
        cells[:] = finder(xy[:, 0], xy[:, 1])
    except ValueError:  # some point is off the straight mesh: one at a time
        for i, (x, y) in enumerate(xy):
            try:
                cells[i] = finder(np.array([x]), np.array([y]))[0]
            except ValueError:
                cells[i] = _curved_cell(system, xy[i])
    missing = np.flatnonzero(cells < 0)
    if missing.size:
        x, y = xy[missing[0]]
        raise OutsideDomain(f"point ({x:.6g}, {y:.6g}) m is off the mesh")
    mapping = system.basis.mapping
    if system.basis.mesh is mesh:  # straight triangles: the affine inverse
        return cells, mapping.invF(xy.T[:, :, None], tind=cells)
    return cells, _inverse(mapping, xy.T[:, :, None], cells)


def _curved_cell(system: System, point: FloatArray) -> int:
    """The curved triangle holding a point off the straight mesh, or -1."""
    if system.basis.mesh is system.domain.mesh or not system.domain.curves:
        return -1
    mesh = system.domain.mesh
    facets = np.concatenate([system.domain.parts[p] for p in system.domain.curves])
    candidates = np.unique(mesh.f2t[0, facets])
    target = np.repeat(point[:, None, None], candidates.size, axis=1)  # (2, c, 1)
    local = _inverse(system.basis.mapping, target, candidates)
    xi, eta = local[0, :, 0], local[1, :, 0]
    inside = (xi >= -_INSIDE) & (eta >= -_INSIDE) & (xi + eta <= 1 + _INSIDE)
    inside &= np.abs(system.basis.mapping.F(local, tind=candidates) - target).max(axis=(0, 2)) < (
        1e-9 * system.domain.size
    )
    return int(candidates[np.argmax(inside)]) if inside.any() else -1


def _inverse(mapping: Any, x: FloatArray, cells: IntArray, iterations: int = 30) -> FloatArray:
    """Newton's inverse of the (curved) map, unclipped: reference coordinates ``(2, n, 1)``."""
    local = np.full(x.shape, 1.0 / 3.0)
    for _ in range(iterations):
        step = np.einsum(
            "ijkl,jkl->ikl", mapping.invDF(local, tind=cells), x - mapping.F(local, tind=cells)
        )
        local = local + step
        if np.abs(step).max() < 1e-14:
            break
    return local


def _sampled(system: System) -> None:
    if system.element == "morley":
        raise InvalidSolve("a Morley field is continuous only at vertices: sample an Argyris one")


def _points(points: ArrayLike) -> FloatArray:
    xy = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] == 0 or not np.isfinite(xy).all():
        raise OutsideDomain(f"points must be finite (x, y) pairs, not shape {np.shape(points)}")
    return xy
