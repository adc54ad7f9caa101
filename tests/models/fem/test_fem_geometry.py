"""Domains: the builders' parts and curves, mesh files, gmsh (optional), the local element."""

from __future__ import annotations

import ctypes
import math
import signal
import sys
import threading
from pathlib import Path

import meshio
import numpy as np
import pytest
from fem_cases import UNIT_PLATE
from skfem import Basis, ElementTriArgyris

from membrane_models import fem
from membrane_models.fem import forms
from membrane_models.fem.elements import LocalArgyris
from membrane_models.fem.gmsh_mesher import keeping_sigpipe


def test_a_rectangle_names_its_four_sides() -> None:
    domain = fem.rectangle(2.0, 1.0, 0.25, origin=(1.0, -0.5))
    assert set(domain.parts) == {"left", "right", "bottom", "top"}
    assert domain.curves == {}
    p, facets = domain.mesh.p, domain.mesh.facets
    for name, axis, value, count in [
        ("left", 0, 1.0, 4),
        ("right", 0, 3.0, 4),
        ("bottom", 1, -0.5, 8),
        ("top", 1, 0.5, 8),
    ]:
        ends = p[:, facets[:, domain.parts[name]]]
        assert np.allclose(ends[axis], value) and domain.parts[name].size == count
    assert domain.area == pytest.approx(2.0)
    assert domain.size == pytest.approx(0.25 * math.sqrt(2))


def test_a_disk_has_its_rim_on_the_exact_circle_and_edges_within_size() -> None:
    domain = fem.disk(0.3, 0.05, center=(0.1, 0.2))
    assert set(domain.parts) == {"rim"} and domain.size <= 0.05
    rim = domain.mesh.p[:, np.unique(domain.mesh.facets[:, domain.parts["rim"]])]
    assert np.allclose(np.hypot(rim[0] - 0.1, rim[1] - 0.2), 0.3)
    frame = domain.curves["rim"].frame(np.array([[0.4], [0.2]]))
    assert np.allclose(frame.normal[:, 0], [1, 0]) and np.allclose(frame.tangent[:, 0], [0, 1])
    assert frame.curvature[0] == pytest.approx(1 / 0.3)


def test_an_ellipse_frame_has_the_exact_normal_and_curvature() -> None:
    curve = fem.Ellipse((0.0, 0.0), 2.0, 1.0)
    frame = curve.frame(np.array([[2.0, 0.0], [0.0, 1.0]]))
    assert np.allclose(frame.normal, [[1, 0], [0, 1]])
    assert np.allclose(frame.curvature, [2.0 / 1.0**2, 1.0 / 2.0**2])  # a / b^2, b / a^2
    point = np.array([[2 * math.cos(0.7)], [math.sin(0.7)]])
    assert np.allclose(curve.project(1.01 * point), point)


def test_gmsh_meshes_an_ellipse_and_a_polygon_with_holes() -> None:
    pytest.importorskip("gmsh")
    tall = fem.ellipse(0.3, 0.5, 0.05)  # the major axis along y
    assert set(tall.parts) == {"rim"} and isinstance(tall.curves["rim"], fem.Ellipse)
    assert tall.area == pytest.approx(math.pi * 0.15, rel=0.01)
    holes = [[(0.2, 0.2), (0.4, 0.2), (0.3, 0.4)], [(0.6, 0.6), (0.8, 0.6), (0.8, 0.8), (0.6, 0.8)]]
    domain = fem.polygon([(0, 0), (1, 0), (1, 1), (0, 1)], 0.1, holes=holes)
    assert set(domain.parts) == {"outer", "hole0", "hole1"}
    assert domain.area == pytest.approx(1 - 0.02 - 0.04)
    hole = domain.mesh.p[:, domain.mesh.facets[:, domain.parts["hole1"]]]
    assert hole.min() >= 0.6 - 1e-12 and hole.max() <= 0.8 + 1e-12
    with pytest.raises(fem.InvalidGeometry, match="not inside"):
        fem.polygon([(0, 0), (1, 0), (1, 1)], 0.1, holes=[[(2, 2), (3, 2), (3, 3)]])
    with pytest.raises(fem.InvalidGeometry, match="overlaps"):
        fem.polygon([(0, 0), (1, 0), (1, 1), (0, 1)], 0.1, holes=[holes[1], holes[1]])


def _edge_lengths(domain: fem.Domain) -> tuple[np.ndarray, np.ndarray]:
    """Each edge's length and its midpoint's distance from the origin."""
    ends = domain.mesh.p[:, domain.mesh.facets]  # (2, 2, edges)
    return np.linalg.norm(ends[:, 0] - ends[:, 1], axis=0), np.linalg.norm(ends.mean(1), axis=0)


def test_a_graded_rim_meshes_the_boundary_band_finer_and_leaves_the_next_mesh_alone() -> None:
    pytest.importorskip("gmsh")
    graded = fem.ellipse(1.0, 1.0, 0.4, rim_size=0.04, rim_width=0.05)
    lengths, radii = _edge_lengths(graded)
    assert lengths[radii > 0.98].max() <= 1.5 * 0.04  # the band, at about the rim's edge size
    assert lengths[radii < 0.7].max() > 0.25  # the interior keeps its own
    assert graded.area == pytest.approx(math.pi, rel=1e-3)  # a finer rim, a truer circle
    plain = fem.ellipse(1.0, 1.0, 0.4)
    assert plain.triangles < graded.triangles / 3 and _edge_lengths(plain)[0].min() > 0.15
    with pytest.raises(fem.InvalidGeometry, match="go together"):
        fem.ellipse(1.0, 1.0, 0.4, rim_size=0.04)
    with pytest.raises(fem.InvalidGeometry, match="rim_size <= size"):
        fem.ellipse(1.0, 1.0, 0.4, rim_size=0.5, rim_width=0.05)
    with pytest.raises(fem.InvalidGeometry, match="at most"):
        fem.ellipse(1.0, 1.0, 0.4, rim_size=1e-5, rim_width=0.1)


def test_without_gmsh_the_error_names_the_mesh_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gmsh", None)  # import gmsh raises ImportError
    with pytest.raises(fem.MissingMesher, match=r"membrane-tissue\[mesh\]") as error:
        fem.ellipse(1.0, 0.5, 0.1)
    assert isinstance(error.value, fem.FemError) and "\n" not in str(error.value)


def _square_msh22(path: Path) -> None:
    """A 1 x 1 square's triangles (the rectangle builder's) and its sides as physical lines."""
    domain = fem.rectangle(1.0, 1.0, 0.125)
    mesh = domain.mesh
    lines, tags = [], []
    for tag, name in enumerate(["left", "right", "bottom", "top"], start=1):
        lines.append(mesh.facets[:, domain.parts[name]].T)
        tags.append(np.full(domain.parts[name].size, tag))
    meshio.write(
        path,
        meshio.Mesh(
            _3d(mesh.p),
            [("line", np.concatenate(lines)), ("triangle", mesh.t.T)],
            cell_data={
                "gmsh:physical": [np.concatenate(tags), np.full(mesh.t.shape[1], 5)],
                "gmsh:geometrical": [np.concatenate(tags), np.full(mesh.t.shape[1], 1)],
            },
            field_data={
                "left": np.array([1, 1]),
                "right": np.array([2, 1]),
                "bottom": np.array([3, 1]),
                "top": np.array([4, 1]),
                "body": np.array([5, 2]),
            },
        ),
        file_format="gmsh22",
        binary=False,
    )


def test_a_msh_file_brings_its_physical_lines_as_parts(tmp_path: Path) -> None:
    path = tmp_path / "square.msh"
    _square_msh22(path)
    domain = fem.read_mesh(path)
    assert set(domain.parts) == {"left", "right", "bottom", "top"}
    system = fem.assemble(
        domain,
        UNIT_PLATE,
        {"left": "clamped", "right": "clamped"}
        | {"bottom": "simply_supported", "top": "simply_supported"},
    )
    built = fem.assemble(
        fem.rectangle(1.0, 1.0, 0.125),
        UNIT_PLATE,
        {
            "left": "clamped",
            "right": "clamped",
            "bottom": "simply_supported",
            "top": "simply_supported",
        },
    )
    w = [
        fem.sample(s, fem.solve(s, fem.pressure_load(s, 1.0)), (0.5, 0.5)) for s in (system, built)
    ]
    assert w[0] == pytest.approx(w[1], rel=1e-10)


def _sigpipe_ignored() -> bool:
    """The kernel's record (Python's own, ``signal.getsignal``, misses what native code sets)."""
    status = Path("/proc/self/status").read_text()
    ignored = next(line for line in status.splitlines() if line.startswith("SigIgn:"))
    return bool(int(ignored.split()[1], 16) >> (signal.SIGPIPE - 1) & 1)


def _native_default_sigpipe() -> None:
    """What gmsh's first initialisation in a process does, in C (Python's record unchanged)."""
    libc = ctypes.CDLL(None)
    libc.signal.restype = ctypes.c_void_p
    libc.signal(signal.SIGPIPE, ctypes.c_void_p(0))  # SIG_DFL


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux's /proc")
def test_meshing_leaves_sigpipe_ignored_in_this_and_in_another_thread() -> None:
    """gmsh's first initialisation sets SIGPIPE to its default: the next write to a closed pipe
    would kill the process (a server, a test run) instead of raising BrokenPipeError."""
    pytest.importorskip("gmsh")
    assert _sigpipe_ignored()
    _native_default_sigpipe()
    seen = _sigpipe_ignored()
    signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    assert not seen, "the kernel's record would not show the defect"
    for guarded in (_guarded_default_sigpipe, lambda: fem.ellipse(0.3, 0.2, 0.1)):
        guarded()
        assert _sigpipe_ignored()
        worker = threading.Thread(target=guarded)  # only the main thread may call signal()
        worker.start()
        worker.join()
        assert _sigpipe_ignored()


def _guarded_default_sigpipe() -> None:
    with keeping_sigpipe():
        _native_default_sigpipe()


def test_a_gmsh_written_msh4_file_reads_its_cell_sets(tmp_path: Path) -> None:
    gmsh = pytest.importorskip("gmsh")
    path = tmp_path / "plate.msh"
    with keeping_sigpipe():
        gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        geo = gmsh.model.geo
        points = [geo.addPoint(x, y, 0, 0.2) for x, y in [(0, 0), (1, 0), (1, 1), (0, 1)]]
        lines = [geo.addLine(points[i], points[(i + 1) % 4]) for i in range(4)]
        surface = geo.addPlaneSurface([geo.addCurveLoop(lines)])
        geo.synchronize()
        gmsh.model.addPhysicalGroup(1, lines[:1], name="held")
        gmsh.model.addPhysicalGroup(1, lines[1:], name="loose")
        gmsh.model.addPhysicalGroup(2, [surface], name="skin")
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    domain = fem.read_mesh(path)
    assert set(domain.parts) == {"held", "loose"}
    held = domain.mesh.p[:, domain.mesh.facets[:, domain.parts["held"]]]
    assert np.allclose(held[1], 0.0)  # the bottom line, y = 0
    modes = fem.modes(fem.assemble(domain, UNIT_PLATE, {"held": "clamped"}), 2)
    assert (modes.omega > 0).all()  # a cantilever


def test_a_vtk_file_has_one_boundary_part_and_bad_files_are_refused(tmp_path: Path) -> None:
    mesh = fem.rectangle(1.0, 1.0, 0.5).mesh
    path = tmp_path / "square.vtk"
    meshio.write(path, meshio.Mesh(_3d(mesh.p), [("triangle", mesh.t.T)]))
    domain = fem.read_mesh(path)
    assert set(domain.parts) == {"boundary"} and domain.parts["boundary"].size == 8
    lines = tmp_path / "lines.vtk"
    meshio.write(lines, meshio.Mesh(_3d(mesh.p), [("line", mesh.facets.T)]))
    with pytest.raises(fem.InvalidGeometry, match="no triangles"):
        fem.read_mesh(lines)
    with pytest.raises(FileNotFoundError):
        fem.read_mesh(tmp_path / "missing.msh")
    garbage = tmp_path / "garbage.msh"
    garbage.write_text("not a mesh\n")
    with pytest.raises(fem.InvalidGeometry, match=r"garbage\.msh"):  # meshio would sys.exit(1)
        fem.read_mesh(garbage)


def _3d(points: np.ndarray) -> np.ndarray:
    return np.column_stack([points.T, np.zeros(points.shape[1])])


def test_from_triangles_refuses_what_is_not_a_mesh() -> None:
    points = [(0, 0), (1, 0), (0, 1), (1, 1)]
    with pytest.raises(fem.InvalidGeometry, match="degenerate"):
        fem.from_triangles([(0, 0), (1, 0), (2, 0)], [(0, 1, 2)])
    with pytest.raises(fem.InvalidGeometry, match="not triangle edges"):
        fem.from_triangles(points, [(0, 1, 2), (1, 3, 2)], {"side": [(0, 3)]})
    with pytest.raises(fem.InvalidGeometry, match="points that do not exist"):
        fem.from_triangles(points, [(0, 1, 7)])
    with pytest.raises(fem.InvalidGeometry, match="positive"):
        fem.rectangle(1.0, -1.0, 0.1)
    with pytest.raises(fem.InvalidGeometry, match="at most"):
        fem.rectangle(1.0, 1.0, 1e-4)


def test_the_local_argyris_element_is_scikit_fems_element() -> None:
    """Same DOFs and basis, computed in each triangle's own coordinates (off the origin here)."""
    mesh = fem.rectangle(0.05, 0.03, 0.01, origin=(0.2, 0.1)).mesh
    ours = Basis(mesh, LocalArgyris(), intorder=10)
    theirs = Basis(mesh, ElementTriArgyris(), intorder=10)
    k_ours = forms.bending.assemble(ours, rigidity=1.0, poisson=0.3)
    k_theirs = forms.bending.assemble(theirs, rigidity=1.0, poisson=0.3)
    assert abs(k_ours - k_theirs).max() < 1e-6 * abs(k_theirs).max()
    points = np.array([[0.213, 0.241], [0.117, 0.122]])
    values = ours.probes(points).toarray(), theirs.probes(points).toarray()
    assert np.abs(values[0] - values[1]).max() < 1e-6
