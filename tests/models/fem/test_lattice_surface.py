"""The lattice as a surface (describe's ``triangles``): a grid's cells on the tissue only, a
point list's Delaunay triangles without bridging a concave corner."""

from __future__ import annotations

import itertools

import numpy as np

from membrane_models.fem import disk, from_triangles, rectangle
from membrane_models.fem.lattice_surface import lattice_triangles


def _grid(nx: int, ny: int, lower: float, upper: float) -> np.ndarray:
    x, y = np.meshgrid(np.linspace(lower, upper, nx), np.linspace(lower, upper, ny), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel()])


def _areas(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (points[triangles[:, k]] for k in range(3))
    return 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])


def test_a_rectangles_grid_keeps_every_cell_counter_clockwise() -> None:
    points = _grid(5, 4, 0.0, 0.05)
    triangles = lattice_triangles(points, (5, 4), rectangle(0.05, 0.05, 0.01))
    assert triangles.shape == (2 * 4 * 3, 3) and triangles.dtype == np.int32
    assert (_areas(points, triangles) > 0).all()
    assert np.isclose(_areas(points, triangles).sum(), 0.05**2, rtol=1e-12)


def test_a_disks_grid_keeps_its_inside_only() -> None:
    radius = 0.02
    domain = disk(radius, 0.004, center=(radius, radius))
    points = _grid(17, 17, 0.0, 2 * radius)
    triangles = lattice_triangles(points, (17, 17), domain)
    corners = points[triangles]
    assert 0 < len(triangles) < 2 * 16 * 16
    assert np.linalg.norm(corners - radius, axis=2).max() <= radius * (1 + 1e-9)
    # A cell well inside is kept: the centre's four cells, eight triangles.
    centre = 8 * 17 + 8
    assert (triangles == centre).any(axis=1).sum() == 6  # a grid vertex's six triangles


def test_a_point_list_on_an_l_shape_is_not_bridged_across_its_corner() -> None:
    # An L: the unit square's three quarters, without [0.5, 1] x [0.5, 1].
    corners = np.array([[0, 0], [1, 0], [1, 0.5], [0.5, 0.5], [0.5, 1], [0, 1], [0.5, 0], [0, 0.5]])
    shape = from_triangles(
        corners * 0.01, [[0, 6, 7], [6, 3, 7], [6, 1, 2], [6, 2, 3], [7, 3, 4], [7, 4, 5]]
    )
    rng = np.random.default_rng(3)
    points = rng.uniform(0.0005, 0.0095, (400, 2))
    inside = ~((points[:, 0] > 0.0045) & (points[:, 1] > 0.0045))
    # Points along the L's outline too (as a lattice on a shape has), so that Delaunay's edges
    # follow it and the kept triangles tile the L exactly.
    outline = [0, 1, 2, 3, 4, 5, 0]
    t = np.linspace(0.0, 1.0, 21)[:-1, None]
    edges = [corners[a] + t * (corners[b] - corners[a]) for a, b in itertools.pairwise(outline)]
    points = np.vstack([points[inside], *(edge * 0.01 for edge in edges)])
    triangles = lattice_triangles(points, (len(points),), shape)
    area = np.abs(_areas(points, triangles)).sum()
    assert np.isclose(area, 0.75e-4, rtol=1e-9), area  # the L's area: its missing quarter left out
    assert (_areas(points, triangles) > 0).all()


def test_a_wrong_inside_test_would_be_caught() -> None:
    """Keeping every Delaunay triangle covers the L's missing quarter: the area test above
    sees the difference."""
    corners = np.array([[0, 0], [1, 0], [1, 0.5], [0.5, 0.5], [0.5, 1], [0, 1]]) * 0.01
    from scipy.spatial import Delaunay

    hull_area = np.abs(_areas(corners, Delaunay(corners).simplices)).sum()
    assert not np.isclose(hull_area, 0.75e-4, rtol=1e-3)
