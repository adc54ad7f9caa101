"""The plate's triangles, Argyris and Morley, evaluated in each triangle's own coordinates.

scikit-fem defines these elements through their DOFs (``ElementGlobal``): each triangle's
basis is the power basis combined by the inverse of its DOFs' Vandermonde matrix. It builds
that power basis in global coordinates, once per basis function, which is slow on a few
thousand triangles (the 21 Argyris functions evaluate the 21 monomials 21 times) and
ill-conditioned far from the origin (a 2 mm triangle at 50 mm: monomials of x/h ~ 25 to the
fifth). These subclasses keep scikit-fem's DOFs, their numbering and their edge orientation
(an interior edge's normal turns its low-to-high vertex direction clockwise; a boundary edge's
points out), and change only how the basis is computed:

- coordinates xi = (x - c) / s per triangle (c its centroid, s its longest edge), so the
  Vandermonde matrix is O(1) and its derivative rows carry 1/s^order exactly;
- the monomials and their derivatives are evaluated once per set of points and every basis
  function is one contraction with the inverse, cached until the points change.

The result is the same element (``tests/models/fem``: the stiffness matches scikit-fem's).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from skfem import ElementTriArgyris, ElementTriMorley
from skfem.element import DiscreteField

__all__ = ["LocalArgyris", "LocalMorley"]

FloatArray = NDArray[np.float64]
_DERIVATIVE = {"u": (), "u_x": (0,), "u_y": (1,), "u_xx": (0, 0), "u_xy": (0, 1), "u_yy": (1, 1)}


class _Local:
    """The local evaluation (module docstring), for an element with vertex and edge DOFs."""

    nodal_dofs: int
    facet_dofs: int
    maxdeg: int
    dofnames: list[str]

    def __init__(self) -> None:
        self._mesh: Any = None
        self._coefficients: FloatArray | None = None
        self._cache: tuple[Any, Any, Any, list[FloatArray]] | None = None
        self._powers = [(a, b) for a in range(self.maxdeg + 1) for b in range(self.maxdeg + 1 - a)]

    def gbasis(self, mapping: Any, X: Any, i: int, tind: Any = None) -> tuple[DiscreteField]:
        mesh = mapping.mesh
        if self._mesh is not mesh:
            self._mesh, self._coefficients, self._cache = mesh, self._inverse(mesh), None
        cache = self._cache  # the same points for every i: evaluate them once
        if cache is None or cache[0] is not mapping or cache[1] is not X or cache[2] is not tind:
            cells = np.arange(mesh.t.shape[1]) if tind is None else tind
            cache = (mapping, X, tind, self._evaluate(mapping, X, cells))
            self._cache = cache
        value, grad, hess = cache[3]
        return (DiscreteField(value=value[i], grad=grad[:, i], hess=hess[:, :, i]),)

    def _frame(self, mesh: Any) -> tuple[FloatArray, FloatArray]:
        """Each triangle's centroid ``(2, E)`` and longest edge ``(E,)``."""
        corners = mesh.p[:, mesh.t]  # (2, 3, E)
        edges = corners - np.roll(corners, -1, axis=1)
        return corners.mean(axis=1), np.linalg.norm(edges, axis=0).max(axis=0)

    def _monomials(self, xi: FloatArray, order: int) -> dict[tuple[int, ...], FloatArray]:
        """d^k/dxi^k of every monomial at local points ``(2, ...)``: (diff) -> ``(M, ...)``."""
        powers_x = [np.ones_like(xi[0])]
        powers_y = [np.ones_like(xi[1])]
        for _ in range(self.maxdeg):
            powers_x.append(powers_x[-1] * xi[0])
            powers_y.append(powers_y[-1] * xi[1])
        table = {}
        for k in range(order + 1):
            for diff in itertools.product((0, 1), repeat=k):
                dx, dy = diff.count(0), diff.count(1)
                rows = []
                for a, b in self._powers:
                    if a < dx or b < dy:
                        rows.append(np.zeros_like(xi[0]))
                        continue
                    factor = math.perm(a, dx) * math.perm(b, dy)
                    rows.append(factor * powers_x[a - dx] * powers_y[b - dy])
                table[diff] = np.array(rows)
        return table

    def _inverse(self, mesh: Any) -> FloatArray:
        """Per triangle, the power-basis coefficients ``(E, M, N)`` of the N basis functions."""
        center, scale = self._frame(mesh)
        corners = (mesh.p[:, mesh.t] - center[:, None, :]) / scale[None, None, :]  # (2, 3, E)
        count = len(self._powers)
        rows: list[FloatArray] = []  # DOF functionals on the monomials, in xi: (E, M) each
        orders: list[int] = []
        at_vertices = [self._monomials(corners[:, v, :], 2) for v in range(3)]
        names = self.dofnames[: self.nodal_dofs]
        for v in range(3):
            for name in names:
                diff = _DERIVATIVE[name]
                rows.append(at_vertices[v][diff].T)
                orders.append(len(diff))
        normals = _edge_normals(mesh)  # (3, 2, E)
        for e in range(3):
            middle = 0.5 * (corners[:, e, :] + corners[:, (e + 1) % 3, :])
            table = self._monomials(middle, 1)
            rows.append((normals[e, 0] * table[(0,)] + normals[e, 1] * table[(1,)]).T)
            orders.append(1)
        vandermonde = np.stack(rows, axis=1)  # (E, N, M), in xi
        if vandermonde.shape[1] != count:
            raise AssertionError("the element's DOFs do not match its power basis")
        inverse = np.linalg.inv(vandermonde)  # (E, M, N): L~_j(phi~_i) = delta
        # L_j = s^-order_j L~_j, so phi_i = s^order_i phi~_i
        return np.asarray(inverse * scale[:, None, None] ** np.array(orders)[None, None, :])

    def _evaluate(self, mapping: Any, X: Any, tind: Any) -> list[FloatArray]:
        center, scale = self._frame(mapping.mesh)
        x = mapping.F(X, tind=tind)  # (2, E, Q)
        s = scale[tind][:, None]
        xi = (x - center[:, tind][:, :, None]) / s
        table = self._monomials(xi, 2)
        coefficients = self._coefficients
        assert coefficients is not None
        c = np.swapaxes(coefficients[tind], 1, 2)  # (E, N, M)

        def combine(monomials: FloatArray) -> FloatArray:  # (M, E, Q) -> (N, E, Q)
            return np.swapaxes(np.matmul(c, np.swapaxes(monomials, 0, 1)), 0, 1)

        value = combine(table[()])
        grad = np.stack([combine(table[(d,)]) / s for d in (0, 1)])
        hess = np.empty((2, 2, *value.shape))
        for d1, d2 in itertools.product((0, 1), repeat=2):
            hess[d1, d2] = combine(table[(d1, d2)]) / (s * s)
        return [value, grad, hess]


def _edge_normals(mesh: Any) -> FloatArray:
    """scikit-fem's edge normals per triangle ``(3, 2, E)`` (module docstring)."""
    corners = mesh.p[:, mesh.t]  # (2, 3, E)
    normals = np.empty((3, 2, corners.shape[2]))
    for e, (a, b) in enumerate(((0, 1), (1, 2), (0, 2))):  # low to high: t is sorted
        d = corners[:, a, :] - corners[:, b, :]
        normals[e] = np.stack([d[1], -d[0]]) / np.linalg.norm(d, axis=0)
    boundary = np.isin(mesh.t2f, mesh.boundary_facets())  # (3, E)
    centroid = corners.mean(axis=1)
    for e in range(3):
        middle = 0.5 * (corners[:, e, :] + corners[:, (e + 1) % 3, :])
        inward = np.einsum("ie,ie->e", normals[e], middle - centroid) < 0
        normals[e][:, boundary[e] & inward] *= -1.0
    return normals


class LocalArgyris(_Local, ElementTriArgyris):
    """``ElementTriArgyris`` (C1 quintic), evaluated locally."""


class LocalMorley(_Local, ElementTriMorley):
    """``ElementTriMorley`` (nonconforming quadratic), evaluated locally."""
