"""A domain read from a mesh file (Gmsh .msh, VTK, any format meshio reads).

The file's triangles (a quadratic triangle's corners) make the mesh; coordinates are taken in
metres and must lie in the plane z = 0. Boundary parts come from the file's named line cells:
Gmsh physical curve groups (``.msh`` 4, meshio's cell sets; ``.msh`` 2.2, the
``gmsh:physical`` tags and their names), any other named line cell set likewise; a file
without them (VTK) gets one part, "boundary". Every named line must be a boundary edge of the
triangles. A file's parts are straight unless ``curves`` gives their exact curves.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.fem.errors import InvalidGeometry
from membrane_models.fem.geometry import Curve, Domain, from_triangles

__all__ = ["read_mesh"]

IntArray = NDArray[np.int64]
_TRIANGLES = ("triangle", "triangle6", "triangle7")
_LINES = ("line", "line3")


def read_mesh(path: str | os.PathLike[str], curves: Mapping[str, Curve] | None = None) -> Domain:
    """The domain in the file at ``path`` (module docstring). A missing or unreadable file is
    an ``OSError`` naming it; a file meshio cannot parse (which meshio answers by exiting the
    process: caught here), or without triangles, an ``InvalidGeometry``."""
    import meshio

    with open(path, "rb"):  # a missing or unreadable file: the OSError, with its name
        pass
    name = os.fspath(path)
    kind = "gmsh" if str(name).lower().endswith(".msh") else None  # not ansys's .msh first
    attempts = io.StringIO()  # meshio prints each format it failed to read
    try:
        with contextlib.redirect_stdout(attempts), contextlib.redirect_stderr(attempts):
            mesh = meshio.read(name, file_format=kind)
    except OSError:
        raise
    except (Exception, SystemExit) as error:  # meshio exits the process when no reader fits
        tried = " ".join(attempts.getvalue().split())
        reason = str(error) if not isinstance(error, SystemExit) else "no reader fits"
        raise InvalidGeometry(f"{name}: {reason}{f' ({tried})' if tried else ''}") from None
    points = np.asarray(mesh.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[0] == 0:
        raise InvalidGeometry(f"{name} has no points")
    if points.shape[1] == 3:
        extent = float(np.ptp(points[:, :2], axis=0).max())
        if not float(np.abs(points[:, 2]).max()) <= 1e-9 * extent:
            raise InvalidGeometry(f"{name} is not a plane mesh in z = 0")
    triangles = [block.data[:, :3] for block in mesh.cells if block.type in _TRIANGLES]
    if not triangles:
        kinds = ", ".join(sorted({block.type for block in mesh.cells})) or "none"
        raise InvalidGeometry(f"{name} has no triangles (cells: {kinds})")
    lines = _named_lines(mesh)
    return from_triangles(points[:, :2], np.concatenate(triangles), lines or None, curves)


def _named_lines(mesh: Any) -> dict[str, IntArray]:
    """Named line cells: cell sets first, else gmsh physical tags with their field names."""
    blocks = mesh.cells
    named: dict[str, list[IntArray]] = {}
    for name, per_block in mesh.cell_sets.items():
        if name.startswith("gmsh:"):
            continue
        for block, ids in zip(blocks, per_block, strict=True):
            if block.type in _LINES and ids is not None and len(ids):
                named.setdefault(name, []).append(block.data[np.asarray(ids), :2])
    if not named and "gmsh:physical" in mesh.cell_data:
        names = {int(tag): name for name, (tag, dim) in mesh.field_data.items() if int(dim) == 1}
        for block, tags in zip(blocks, mesh.cell_data["gmsh:physical"], strict=True):
            if block.type not in _LINES:
                continue
            for tag in np.unique(tags):
                name = names.get(int(tag), f"physical{int(tag)}")
                named.setdefault(name, []).append(block.data[tags == tag, :2])
    return {name: np.concatenate(parts).astype(np.int64) for name, parts in named.items()}
