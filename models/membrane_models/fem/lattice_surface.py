"""The lattice as a surface: triangles over its points that cover the tissue and nothing else.

A viewer draws a physical scene's frames as a shaded surface, so ``describe`` gives the
lattice's own triangles (indices into its points) rather than the FEM mesh's: the frame's values
live at the lattice points. A grid (``shape`` (nx, ny), point ``i * ny + j``) is split cell by
cell into two triangles, kept when all three corners lie on the tissue (a disk's grid keeps its
inside); a point list is triangulated by Delaunay (scipy) and a triangle kept when its centroid
lies on the tissue, so a concave shape or a hole is not bridged.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import Delaunay

from membrane_models.fem.geometry import Domain
from membrane_models.fem.inside import inside_boundary

__all__ = ["lattice_triangles"]

IntArray = NDArray[np.int32]


def lattice_triangles(
    points: NDArray[np.float64], shape: tuple[int, ...], domain: Domain
) -> IntArray:
    """The lattice's triangles on ``domain``: ``(m, 3)`` indices into ``points`` ``(n, 2)`` (m),
    counter-clockwise in (x, y)."""
    xy = np.asarray(points, dtype=np.float64)
    if len(shape) == 2:
        corners = _grid_triangles(*shape)
        keep = _on(domain, xy)[corners].all(axis=1)
    else:
        corners = _delaunay(xy)
        keep = _on(domain, xy[corners].mean(axis=1))
    return np.ascontiguousarray(corners[keep], dtype=np.int32)


def _grid_triangles(nx: int, ny: int) -> IntArray:
    """Two triangles per cell of an x-major grid, counter-clockwise."""
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = (i * ny + j).ravel()
    b, c, d = a + ny, a + 1, a + ny + 1  # (i+1, j), (i, j+1), (i+1, j+1)
    return np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)]).astype(np.int32)


def _delaunay(xy: NDArray[np.float64]) -> IntArray:
    if xy.shape[0] < 3:
        return np.zeros((0, 3), dtype=np.int32)
    simplices = Delaunay(xy).simplices.astype(np.int32)
    e1 = xy[simplices[:, 1]] - xy[simplices[:, 0]]
    e2 = xy[simplices[:, 2]] - xy[simplices[:, 0]]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    simplices[clockwise] = simplices[clockwise][:, [0, 2, 1]]
    return simplices


def _on(domain: Domain, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which points lie on the tissue (its boundary included)."""
    mesh = domain.mesh
    facets = mesh.facets[:, mesh.boundary_facets()]
    segments = np.ascontiguousarray(np.transpose(mesh.p[:, facets], (2, 1, 0)))
    return inside_boundary(xy, segments, 1e-9 * domain.size)
