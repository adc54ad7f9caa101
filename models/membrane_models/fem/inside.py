"""Which points lie inside a meshed shape: crossings of the mesh's boundary, all points at once.

A point is inside when a ray from it along +x crosses the boundary segments an odd number of
times (holes included, since their edges are boundary edges too), or when it lies on a segment
(the closed shape: a point on a clamped edge is in the domain). One vectorised pass over
points x segments: the mesh's element finder locates one point per call, a few thousand
times slower for the grids of centres the live tables are built on.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["inside_boundary"]

FloatArray = NDArray[np.float64]
_BLOCK = 4096  # points per pass (points x segments temporaries)


def inside_boundary(points: FloatArray, segments: FloatArray, on_edge: float) -> NDArray[np.bool_]:
    """For points (n, 2) and boundary segments (s, 2, 2) (m), whether each point is inside or
    within ``on_edge`` (m) of the boundary."""
    xy = np.atleast_2d(np.asarray(points, dtype=np.float64))
    out = np.empty(xy.shape[0], dtype=bool)
    for start in range(0, xy.shape[0], _BLOCK):
        out[start : start + _BLOCK] = _inside(xy[start : start + _BLOCK], segments, on_edge)
    return out


def _inside(xy: FloatArray, segments: FloatArray, on_edge: float) -> NDArray[np.bool_]:
    x, y = xy[:, 0:1], xy[:, 1:2]
    x1, y1 = segments[None, :, 0, 0], segments[None, :, 0, 1]
    dx, dy = segments[None, :, 1, 0] - x1, segments[None, :, 1, 1] - y1
    t = np.clip(((x - x1) * dx + (y - y1) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
    near = np.min(np.hypot(x1 + t * dx - x, y1 + t * dy - y), axis=1) <= on_edge
    straddles = (y1 > y) != (y1 + dy > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = x1 + (y - y1) * dx / dy
    odd = np.count_nonzero(straddles & (x < crossing), axis=1) % 2 == 1
    return np.asarray(near | odd)
