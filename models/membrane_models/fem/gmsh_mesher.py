"""Shapes scikit-fem cannot mesh alone, meshed by gmsh: an ellipse, a polygon with holes.

gmsh is optional (the ``mesh`` extra): it is imported here, on first use, and its absence is a
``MissingMesher`` naming the extra. It runs headless (no GUI, no terminal output, no config
files read) and leaves the process's signal dispositions as it found them: SIGINT by
``interruptible=False``, SIGPIPE by ``keeping_sigpipe`` (gmsh's initialisation resets it to the
default, which kills the process at its next write to a closed pipe or socket, where Python
ignores it and raises ``BrokenPipeError``). gmsh is one global state per process, so a call
here is not thread-safe; a session the caller opened is kept open, one opened here is closed.

Each function returns plain arrays: points ``(n, 2)`` (m), triangles ``(k, 3)`` and, per
named physical curve group, its boundary lines ``(j, 2)`` (point indices); ``geometry`` turns
them into a ``Domain``.
"""

from __future__ import annotations

import ctypes
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.fem.errors import InvalidGeometry, MissingMesher

__all__ = ["EXTRA_HINT", "keeping_sigpipe", "mesh_ellipse", "mesh_polygon"]

EXTRA_HINT = "pip install 'membrane-tissue[mesh]'"
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Meshed = tuple[FloatArray, IntArray, dict[str, IntArray]]
_TRIANGLE, _LINE = 2, 1  # gmsh element types: 3-node triangle, 2-node line


def mesh_ellipse(
    center: tuple[float, float],
    a: float,
    b: float,
    size: float,
    rim: tuple[float, float] | None = None,
) -> Meshed:
    """An ellipse, semi-axes ``a`` along x and ``b`` along y; one curve group, "rim".

    ``rim`` = (edge size, width): triangles of that edge within that distance of the rim,
    growing to ``size`` over as much again inward (a clamped plate's boundary layer, where
    a stretched plate bends over a few times sqrt(D / N)).
    """

    def build(gmsh: Any) -> dict[str, list[int]]:
        if a >= b:
            gmsh.model.occ.addDisk(center[0], center[1], 0.0, a, b)
        else:  # OpenCASCADE wants the major axis first: lay it along y
            gmsh.model.occ.addDisk(
                center[0], center[1], 0.0, b, a, zAxis=[0, 0, 1], xAxis=[0, 1, 0]
            )
        gmsh.model.occ.synchronize()
        curves = [tag for _, tag in gmsh.model.getEntities(1)]
        if rim is not None:
            _grade_towards(gmsh, curves, size, *rim)
        return {"rim": curves}

    return _mesh(build, size)


def _grade_towards(gmsh: Any, curves: list[int], size: float, edge: float, width: float) -> None:
    """A background size field: ``edge`` within ``width`` of ``curves``, ``size`` beyond twice
    that, linear between (gmsh's Distance and Threshold fields)."""
    field = gmsh.model.mesh.field
    distance = field.add("Distance")
    field.setNumbers(distance, "CurvesList", curves)
    field.setNumber(distance, "Sampling", 400)
    threshold = field.add("Threshold")
    field.setNumber(threshold, "InField", distance)
    field.setNumber(threshold, "SizeMin", edge)
    field.setNumber(threshold, "SizeMax", size)
    field.setNumber(threshold, "DistMin", width)
    field.setNumber(threshold, "DistMax", 2.0 * width)
    field.setAsBackgroundMesh(threshold)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)


def mesh_polygon(outer: FloatArray, holes: Sequence[FloatArray], size: float) -> Meshed:
    """A polygon ``(n, 2)`` with polygonal holes; curve groups "outer", "hole0", ..."""

    def build(gmsh: Any) -> dict[str, list[int]]:
        geo = gmsh.model.geo
        groups: dict[str, list[int]] = {}
        loops = []
        for name, vertices in [("outer", outer), *((f"hole{i}", h) for i, h in enumerate(holes))]:
            points = [geo.addPoint(float(x), float(y), 0.0, size) for x, y in vertices]
            lines = [
                geo.addLine(points[i], points[(i + 1) % len(points)]) for i in range(len(points))
            ]
            loops.append(geo.addCurveLoop(lines))
            groups[name] = lines
        geo.addPlaneSurface(loops)
        geo.synchronize()
        return groups

    return _mesh(build, size)


def _mesh(build: Callable[[Any], dict[str, list[int]]], size: float) -> Meshed:
    """Build the model, mesh it with triangles of edge about ``size`` and read it back."""
    with _session() as gmsh:
        gmsh.model.add("membrane")
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 1)
        try:
            return _read(gmsh, build(gmsh), size)
        finally:
            gmsh.model.remove()


def _read(gmsh: Any, groups: dict[str, list[int]], size: float) -> Meshed:
    gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    try:
        gmsh.model.mesh.generate(2)
    except Exception as error:  # gmsh raises a bare Exception with its last error
        raise InvalidGeometry(f"gmsh could not mesh the shape: {error}") from error
    tags, coords, _ = gmsh.model.mesh.getNodes()
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(tags.size)
    points = np.asarray(coords, dtype=np.float64).reshape(-1, 3)[:, :2]
    triangles = _nodes(gmsh, 2, -1, _TRIANGLE, 3)
    if triangles.size == 0:
        raise InvalidGeometry("gmsh made no triangles for the shape")
    lines = {
        name: index[np.concatenate([_nodes(gmsh, 1, tag, _LINE, 2) for tag in curves])]
        for name, curves in groups.items()
    }
    return points, index[triangles], lines


def _nodes(gmsh: Any, dim: int, tag: int, kind: int, count: int) -> IntArray:
    """The node tags ``(k, count)`` of the elements of one type on an entity (-1: all)."""
    types, _, nodes = gmsh.model.mesh.getElements(dim, tag)
    found = [np.asarray(n, dtype=np.int64) for t, n in zip(types, nodes, strict=True) if t == kind]
    return np.concatenate(found).reshape(-1, count) if found else np.zeros((0, count), np.int64)


@contextmanager
def _session() -> Iterator[Any]:
    """gmsh, initialised headless; finalised after unless the caller had it open."""
    try:
        import gmsh
    except (ImportError, OSError) as error:
        raise MissingMesher(f"this shape is meshed by gmsh ({error}): {EXTRA_HINT}") from error
    opened = not gmsh.isInitialized()
    if opened:
        with keeping_sigpipe():
            gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 1)
        yield gmsh
    finally:
        if opened:
            gmsh.finalize()


@contextmanager
def keeping_sigpipe() -> Iterator[None]:
    """SIGPIPE's disposition as it was before the block, whatever native code did inside it."""
    sigpipe = getattr(signal, "SIGPIPE", None)
    if sigpipe is None:  # Windows: no such signal
        yield
        return
    before = signal.getsignal(sigpipe)  # Python's record; native code changes the kernel's only
    try:
        yield
    finally:
        _set_disposition(sigpipe, before)


def _set_disposition(signum: int, handler: Any) -> None:
    if threading.current_thread() is threading.main_thread():
        signal.signal(signum, handler)
    elif handler in (signal.SIG_IGN, signal.SIG_DFL):  # only the main thread may call signal()
        libc = ctypes.CDLL(None, use_errno=True)
        libc.signal.restype = ctypes.c_void_p
        libc.signal(signum, ctypes.c_void_p(int(handler)))
