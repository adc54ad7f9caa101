"""Where the tissue is: a triangle mesh, its named boundary parts and their exact curves.

A ``Domain`` is a scikit-fem ``MeshTri`` (coordinates in metres), named boundary parts (arrays
of the mesh's facet indices: a boundary condition is set per part) and, for a curved part, its
exact ``Curve``: the outward normal, the tangent and the curvature at a boundary point, which
the plate's simply supported edge needs (``boundary``: imposed in the polygon's frame, it
converges to another plate, Babuska's paradox) and where a membrane's quadratic elements put
their boundary midpoints. A straight part needs no curve: its facets' own frame is exact.

Conventions: the normal ``n`` points out of the domain, the tangent is ``t = (-n_y, n_x)``
(counter-clockwise around an outer boundary), and the curvature ``kappa`` (1/m) is positive
where the domain is convex, so that along the boundary ``dt/ds = -kappa n`` and
``dn/ds = kappa t``.

Builders: ``rectangle`` (parts "left", "right", "bottom", "top") and ``disk`` ("rim") with
scikit-fem's own meshes; ``ellipse`` ("rim") and ``polygon`` ("outer", "hole0", ...) with gmsh
(``gmsh_mesher``, the ``mesh`` extra). ``read_mesh`` (``mesh_file``) reads a file, and
``from_triangles`` builds a domain from arrays. ``size`` is a target edge length in metres.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from skfem import MeshTri

from membrane_models.fem.errors import InvalidGeometry

__all__ = [
    "MAX_TRIANGLES",
    "Circle",
    "Curve",
    "Domain",
    "Ellipse",
    "Frame",
    "disk",
    "ellipse",
    "from_triangles",
    "polygon",
    "rectangle",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
MAX_TRIANGLES = 1_000_000  # a mesh larger than this is refused before it is built
_ON_CURVE = 1e-6  # a curved part's vertices lie this close to its curve (x the domain's extent)


@dataclass(frozen=True)
class Frame:
    """A boundary's frame at points (shape ``(2, n)`` vectors, ``(n,)`` curvature).

    Attributes:
        normal: unit outward normals.
        tangent: unit tangents, ``(-n_y, n_x)``.
        curvature: 1/m, positive where the domain is convex (module docstring).
    """

    normal: FloatArray
    tangent: FloatArray
    curvature: FloatArray


class Curve(Protocol):
    """The exact curve of a curved boundary part."""

    def frame(self, points: FloatArray) -> Frame:
        """The frame at points ``(2, n)`` on the curve."""
        ...

    def project(self, points: FloatArray) -> FloatArray:
        """Points ``(2, n)`` near the curve moved onto it (a nearby curve point, not
        necessarily the nearest)."""
        ...


@dataclass(frozen=True)
class Circle:
    """A circle bounding the domain from outside (the domain is inside): centre, radius (m)."""

    center: tuple[float, float]
    radius: float

    def frame(self, points: FloatArray) -> Frame:
        normal = _unit(np.asarray(points, dtype=np.float64) - _column(self.center))
        tangent = np.stack([-normal[1], normal[0]])
        return Frame(normal, tangent, np.full(normal.shape[1], 1.0 / self.radius))

    def project(self, points: FloatArray) -> FloatArray:
        center = _column(self.center)
        return center + self.radius * _unit(np.asarray(points, dtype=np.float64) - center)


@dataclass(frozen=True)
class Ellipse:
    """An ellipse bounding the domain from outside: centre, semi-axes along x and y (m)."""

    center: tuple[float, float]
    a: float
    b: float

    def _angle(self, points: FloatArray) -> FloatArray:
        offset = np.asarray(points, dtype=np.float64) - _column(self.center)
        return np.asarray(np.arctan2(offset[1] / self.b, offset[0] / self.a), dtype=np.float64)

    def frame(self, points: FloatArray) -> Frame:
        theta = self._angle(points)
        cos, sin = np.cos(theta), np.sin(theta)
        speed = np.sqrt((self.a * sin) ** 2 + (self.b * cos) ** 2)
        normal = np.stack([self.b * cos, self.a * sin]) / speed
        tangent = np.stack([-normal[1], normal[0]])
        return Frame(normal, tangent, self.a * self.b / speed**3)

    def project(self, points: FloatArray) -> FloatArray:
        theta = self._angle(points)
        return _column(self.center) + np.stack([self.a * np.cos(theta), self.b * np.sin(theta)])


@dataclass(frozen=True, eq=False)
class Domain:
    """A triangle mesh with named boundary parts (module docstring).

    Attributes:
        mesh: the triangles (``skfem.MeshTri``, metres).
        parts: part name -> indices of the mesh's boundary facets (disjoint; a boundary facet in
            no part is free).
        curves: part name -> its exact curve, for the curved parts only.
    """

    mesh: Any
    parts: Mapping[str, IntArray]
    curves: Mapping[str, Curve] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.mesh, MeshTri):
            raise InvalidGeometry(f"a domain is a skfem MeshTri, not {type(self.mesh).__name__}")
        if not (np.diff(self.mesh.t, axis=0) > 0).all():  # the plate's edge normals rely on it
            raise InvalidGeometry(
                "the mesh's triangles must list their vertices in increasing order"
            )
        boundary = np.zeros(self.mesh.facets.shape[1], dtype=bool)
        boundary[self.mesh.boundary_facets()] = True
        owner = np.full(boundary.size, -1)
        parts: dict[str, IntArray] = {}
        for index, (name, facets) in enumerate(self.parts.items()):
            if not isinstance(name, str) or not name:
                raise InvalidGeometry(
                    f"a boundary part's name must be a non-empty string: {name!r}"
                )
            ids = np.unique(np.asarray(facets, dtype=np.int64).ravel())
            if ids.size == 0:
                raise InvalidGeometry(f"boundary part {name!r} has no facets")
            if ids[0] < 0 or ids[-1] >= boundary.size or not boundary[ids].all():
                raise InvalidGeometry(f"boundary part {name!r} names facets off the boundary")
            if (owner[ids] >= 0).any():
                other = list(self.parts)[int(owner[ids][owner[ids] >= 0][0])]
                raise InvalidGeometry(f"boundary parts {other!r} and {name!r} share facets")
            owner[ids] = index
            ids.setflags(write=False)
            parts[name] = ids
        unknown = sorted(set(self.curves) - set(parts))
        if unknown:
            raise InvalidGeometry(f"curves for parts the domain lacks: {', '.join(unknown)}")
        extent = float(np.ptp(self.mesh.p, axis=1).max())
        for name, curve in self.curves.items():
            vertices = self.mesh.p[:, np.unique(self.mesh.facets[:, parts[name]])]
            gap = float(np.abs(curve.project(vertices) - vertices).max())
            if not gap <= _ON_CURVE * extent:
                raise InvalidGeometry(
                    f"the vertices of part {name!r} are {gap:.3g} m off its curve"
                )
        object.__setattr__(self, "parts", MappingProxyType(parts))
        object.__setattr__(self, "curves", MappingProxyType(dict(self.curves)))

    @property
    def size(self) -> float:
        """The longest edge (m)."""
        p, facets = self.mesh.p, self.mesh.facets
        return float(np.linalg.norm(p[:, facets[1]] - p[:, facets[0]], axis=0).max())

    @property
    def area(self) -> float:
        """The mesh's area (m^2)."""
        p, t = self.mesh.p, self.mesh.t
        e1, e2 = p[:, t[1]] - p[:, t[0]], p[:, t[2]] - p[:, t[0]]
        return float(0.5 * np.abs(e1[0] * e2[1] - e1[1] * e2[0]).sum())

    @property
    def triangles(self) -> int:
        return int(self.mesh.t.shape[1])


def from_triangles(
    points: ArrayLike,
    triangles: ArrayLike,
    lines: Mapping[str, ArrayLike] | None = None,
    curves: Mapping[str, Curve] | None = None,
) -> Domain:
    """A domain from arrays: points ``(n, 2)`` (m), triangles ``(k, 3)`` (point indices), named
    boundary lines ``(j, 2)`` (point pairs, each a boundary edge). Points no triangle uses are
    dropped. Without ``lines`` the whole boundary is one part, "boundary"."""
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(triangles)
    if p.ndim != 2 or p.shape[1] != 2 or not np.isfinite(p).all():
        raise InvalidGeometry(f"points must be finite, of shape (n, 2), not {p.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0 or not np.issubdtype(t.dtype, np.integer):
        raise InvalidGeometry(f"triangles must be point indices of shape (k, 3), not {t.shape}")
    if t.min() < 0 or t.max() >= p.shape[0]:
        raise InvalidGeometry("triangles name points that do not exist")
    if t.shape[0] > MAX_TRIANGLES:
        raise InvalidGeometry(f"{t.shape[0]} triangles: at most {MAX_TRIANGLES}")
    used = np.unique(t)
    renumber = np.full(p.shape[0], -1, dtype=np.int64)
    renumber[used] = np.arange(used.size)
    corners = p[t]
    doubled = (corners[:, 1, 0] - corners[:, 0, 0]) * (corners[:, 2, 1] - corners[:, 0, 1]) - (
        corners[:, 1, 1] - corners[:, 0, 1]
    ) * (corners[:, 2, 0] - corners[:, 0, 0])
    if not (np.abs(doubled) > 1e-14 * float(np.ptp(p[used], axis=0).max()) ** 2).all():
        raise InvalidGeometry("the mesh has degenerate (zero-area) triangles")
    mesh = MeshTri(np.ascontiguousarray(p[used].T), np.ascontiguousarray(renumber[t].T))
    if lines is None:
        return Domain(mesh, {"boundary": mesh.boundary_facets()}, curves or {})
    parts = {}
    for name, pairs in lines.items():
        edges = renumber[np.asarray(pairs, dtype=np.int64).reshape(-1, 2)]
        parts[name] = _facets_of(mesh, edges, name)
    return Domain(mesh, parts, curves or {})


def rectangle(
    width: float, height: float, size: float, origin: tuple[float, float] = (0.0, 0.0)
) -> Domain:
    """``[x0, x0 + width] x [y0, y0 + height]`` (m), squares of side at most ``size`` cut in two
    triangles; parts "left", "right", "bottom", "top" (each corner in two of them)."""
    _positive(width=width, height=height, size=size)
    x0, y0 = (float(v) for v in origin)
    nx, ny = max(1, math.ceil(width / size - 1e-9)), max(1, math.ceil(height / size - 1e-9))
    if 2 * nx * ny > MAX_TRIANGLES:
        raise InvalidGeometry(
            f"size {size:g} m makes {2 * nx * ny} triangles: at most {MAX_TRIANGLES}"
        )
    mesh = MeshTri.init_tensor(
        np.linspace(x0, x0 + width, nx + 1), np.linspace(y0, y0 + height, ny + 1)
    )
    tol = 1e-9 * max(width, height)
    sides = {
        "left": lambda x: np.abs(x[0] - x0) < tol,
        "right": lambda x: np.abs(x[0] - x0 - width) < tol,
        "bottom": lambda x: np.abs(x[1] - y0) < tol,
        "top": lambda x: np.abs(x[1] - y0 - height) < tol,
    }
    return Domain(
        mesh,
        {name: mesh.facets_satisfying(test, boundaries_only=True) for name, test in sides.items()},
    )


def disk(radius: float, size: float, center: tuple[float, float] = (0.0, 0.0)) -> Domain:
    """A disk (m): scikit-fem's circle mesh, refined (and smoothed) until its longest edge is at
    most ``size``; part "rim", its exact ``Circle``. The centre is a vertex."""
    _positive(radius=radius, size=size)
    cx, cy = (float(v) for v in center)
    refinements = max(0, math.floor(math.log2(radius / size)))  # a lower bound: 2 R / 2^n
    while True:
        if 4 * 4**refinements > MAX_TRIANGLES:
            raise InvalidGeometry(f"size {size:g} m needs over {MAX_TRIANGLES} triangles")
        unit = MeshTri.init_circle(refinements, smoothed=refinements > 0)
        mesh = MeshTri(radius * unit.p + np.array([[cx], [cy]]), unit.t)
        domain = Domain(
            mesh, {"rim": mesh.boundary_facets()}, {"rim": Circle((cx, cy), float(radius))}
        )
        if domain.size <= size:
            return domain
        refinements += 1


def ellipse(
    a: float,
    b: float,
    size: float,
    center: tuple[float, float] = (0.0, 0.0),
    *,
    rim_size: float | None = None,
    rim_width: float | None = None,
) -> Domain:
    """An ellipse with semi-axes ``a`` (along x) and ``b`` (m), meshed by gmsh; part "rim", its
    exact ``Ellipse``. Needs the ``mesh`` extra.

    ``rim_size`` and ``rim_width`` (m, together): edges of ``rim_size`` within ``rim_width`` of
    the rim, growing to ``size`` over as much again: a clamped edge's boundary layer under large
    deflection, resolved without refining the whole plate."""
    from membrane_models.fem.gmsh_mesher import mesh_ellipse

    _positive(a=a, b=b, size=size)
    _estimate(math.pi * a * b, size)
    rim = None
    if rim_size is not None or rim_width is not None:
        if rim_size is None or rim_width is None:
            raise InvalidGeometry("rim_size and rim_width go together")
        _positive(rim_size=rim_size, rim_width=rim_width)
        if rim_size > size or 2.0 * rim_width >= min(a, b):
            raise InvalidGeometry(
                f"a graded rim needs rim_size <= size ({rim_size:g} > {size:g} m) and twice "
                f"rim_width below the shorter semi-axis ({rim_width:g} m against {min(a, b):g} m)"
            )
        perimeter = 2.0 * math.pi * math.sqrt((a * a + b * b) / 2.0)
        _estimate(2.0 * rim_width * perimeter, rim_size)
        rim = (float(rim_size), float(rim_width))
    cx, cy = (float(v) for v in center)
    points, triangles, lines = mesh_ellipse((cx, cy), float(a), float(b), float(size), rim)
    return from_triangles(points, triangles, lines, {"rim": Ellipse((cx, cy), float(a), float(b))})


def polygon(vertices: ArrayLike, size: float, holes: Sequence[ArrayLike] = ()) -> Domain:
    """A polygon ``(n, 2)`` (m) with polygonal holes, meshed by gmsh; parts "outer", "hole0",
    ... (all straight: no curves). Needs the ``mesh`` extra."""
    from membrane_models.fem.gmsh_mesher import mesh_polygon

    _positive(size=size)
    outer = _loop(vertices, "the polygon")
    inner = [_loop(hole, f"hole {index}") for index, hole in enumerate(holes)]
    for index, hole in enumerate(inner):
        if not _inside(hole, outer).all():
            raise InvalidGeometry(f"hole {index} is not inside the polygon")
        for other in inner[:index]:
            if _inside(hole, other).any() or _inside(other, hole).any():
                raise InvalidGeometry(f"hole {index} overlaps an earlier hole")
    _estimate(_area(outer) - sum(_area(hole) for hole in inner), size)
    points, triangles, lines = mesh_polygon(outer, inner, float(size))
    return from_triangles(points, triangles, lines)


def _facets_of(mesh: Any, edges: IntArray, name: str) -> IntArray:
    """The mesh facets that are the point pairs ``edges`` ``(j, 2)``."""
    if (edges < 0).any():
        raise InvalidGeometry(f"boundary part {name!r} names points no triangle uses")
    count = mesh.p.shape[1]
    facets = np.sort(mesh.facets, axis=0)
    keys = facets[0].astype(np.int64) * count + facets[1]
    order = np.argsort(keys)
    wanted = np.sort(edges, axis=1)
    wanted_keys = wanted[:, 0] * count + wanted[:, 1]
    at = np.clip(np.searchsorted(keys, wanted_keys, sorter=order), 0, keys.size - 1)
    found = order[at]
    if not (keys[found] == wanted_keys).all():
        raise InvalidGeometry(f"boundary part {name!r} has lines that are not triangle edges")
    return np.asarray(found, dtype=np.int64)


def _positive(**values: float) -> None:
    for name, value in values.items():
        real = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if not (real and math.isfinite(value) and value > 0):
            raise InvalidGeometry(f"{name} must be a positive number of metres, not {value!r}")


def _estimate(area: float, size: float) -> None:
    count = 2 * area / (math.sqrt(3) / 4 * 2 * size * size)
    if count > MAX_TRIANGLES:
        raise InvalidGeometry(
            f"size {size:g} m makes about {count:.0f} triangles: at most {MAX_TRIANGLES}"
        )


def _loop(vertices: ArrayLike, what: str) -> FloatArray:
    loop = np.asarray(vertices, dtype=np.float64)
    if loop.ndim != 2 or loop.shape[1] != 2 or loop.shape[0] < 3 or not np.isfinite(loop).all():
        raise InvalidGeometry(
            f"{what} needs at least 3 finite (x, y) vertices, not shape {loop.shape}"
        )
    if np.allclose(loop[0], loop[-1]):
        loop = loop[:-1]
    span = float(np.ptp(loop, axis=0).max())
    if not abs(_area(loop)) > 1e-12 * span * span:
        raise InvalidGeometry(f"{what} has no area")
    edges = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    if not (edges > 1e-12 * span).all():
        raise InvalidGeometry(f"{what} repeats a vertex")
    return loop


def _area(loop: FloatArray) -> float:
    """The shoelace area (positive counter-clockwise)."""
    x, y = loop[:, 0], loop[:, 1]
    return float(0.5 * (x * np.roll(y, -1) - np.roll(x, -1) * y).sum())


def _inside(points: FloatArray, loop: FloatArray) -> NDArray[np.bool_]:
    """Ray casting: which of ``points`` ``(k, 2)`` lie inside the polygon ``loop``."""
    x, y = points[:, 0:1], points[:, 1:2]
    x1, y1 = loop[:, 0], loop[:, 1]
    x2, y2 = np.roll(x1, -1), np.roll(y1, -1)
    crosses = (y1 > y) != (y2 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
    return np.asarray((crosses & (x < at)).sum(axis=1) % 2 == 1)


def _unit(vectors: FloatArray) -> FloatArray:
    return np.asarray(vectors / np.linalg.norm(vectors, axis=0), dtype=np.float64)


def _column(point: tuple[float, float]) -> FloatArray:
    return np.array([[point[0]], [point[1]]], dtype=np.float64)
