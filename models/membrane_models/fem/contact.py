"""Rigid tools pressed into a FEM model, solved exactly on the mesh: the static reference for
the live engine's tools.

A tool (``live.Tool``: a sphere or a flat-ended cylinder pressing along -z, its lowest point
``depth`` below the rest surface) keeps w at or below its surface (``live.tools.tool_surface``)
at every value node under it: the vertices of a membrane assembled on P1 triangles
(``assemble(..., element="p1")``) or of a plate. Each such node carries its contact force as a
nodal force (N). A P2 membrane is refused: its vertices' shares of a positive pressure are <= 0
(the integral of a P2 vertex function over its triangle is 0), so nodal forces >= 0 do not
describe contact on it, and on P1 (an M-matrix stiffness on a Delaunay mesh) the method below
converges monotonically. On a membrane, whose point compliance is logarithmically infinite in
the continuum, the nodal forces depend on the mesh but their totals converge under refinement
(a flat punch's force from the log profile, a sphere's from its contact radius, within 1 % on
the meshes of tests/models/fem/test_fem_contact.py).

With G the rows picking w at the constrained nodes (on the constrained space, ``u = T r``) and
lambda >= 0 their forces (pushing along -z), the static problem is the obstacle problem

    K r + G' lambda = f,   G r <= s,   lambda >= 0,   lambda . (s - G r) = 0,

solved by the primal-dual active set method (Hintermueller, Ito and Kunisch 2002): hold the
active nodes on the surface (a sparse saddle-point solve), release those whose force pulls,
add those the tissue crosses, until nothing changes. It is block principal pivoting on the
nodal problem (``live.contact.solve_points``), on the sparse K rather than a dense compliance;
should an active set come back (a cycle, possible where K is not an M-matrix) it flips one node
at a time from then on (Murty's least-index rule), which ends for K positive definite. About one
solve per ring of nodes between the contact's edge and the tool's rim in practice.

Between nodes the FEM field is not constrained: a curved tool may dip below its surface there
by about its sag over half an element (sphere: h^2 / (8 R)). Units: SI (m, N).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.linalg import splu

from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidLoad, InvalidSolve
from membrane_models.fem.models import Membrane
from membrane_models.live.inputs import parse_tools
from membrane_models.live.interface import Tool, ToolReading
from membrane_models.live.tools import tool_points, tool_readings

__all__ = ["Pressed", "press", "solve_obstacle"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
_TOLERANCE = 1e-10  # relative to the largest surface depth / force: what counts as zero


@dataclass(frozen=True, eq=False)
class Pressed:
    """A static press (module docstring).

    Attributes:
        deflection: u on every DOF (``sampling.sample`` reads w from it, m).
        points: the constrained nodes, (nodes, 2) (m).
        surface: the lowest tool surface over each (m, along +z).
        owner: the tool each node's surface belongs to.
        forces: each node's contact force (N, >= 0, pushing along -z).
        readings: each tool's total force, centre, contacts, nodes, gap and penetration, as
            the live engine reports them (``live.ToolReading``; its "points" are nodes here).
    """

    deflection: FloatArray
    points: FloatArray
    surface: FloatArray
    owner: IntArray
    forces: FloatArray
    readings: tuple[ToolReading, ...]


def press(system: System, tools: Sequence[Tool], load: ArrayLike | None = None) -> Pressed:
    """``tools`` pressed into ``system`` under an optional external ``load`` (N per DOF).

    Raises:
        InvalidTool: a tool that is not one (``live.inputs.parse_tools``).
        InvalidLoad: a load of the wrong shape or not finite.
        InvalidSolve: a membrane on P2 triangles, or a tool pressed below the rest surface
            where the tissue cannot move.
    """
    if isinstance(system.model, Membrane) and system.element != "p1":
        raise InvalidSolve(
            f"a press on a membrane needs p1 triangles, not {system.element}: assemble(..., "
            'element="p1") (P2 vertices take no share of a pressure, so their nodal forces '
            "cannot be held >= 0)"
        )
    checked = parse_tools(tools, 2)
    f = _load(system, load)
    dofs, coordinates = _value_nodes(system)
    movable = np.diff(system.transform.tocsr().indptr)[dofs] > 0
    rows = tool_points(checked, coordinates, movable, max_points=dofs.size)
    picks = sp.csr_matrix(
        (np.ones(rows.count), (np.arange(rows.count), dofs[rows.indices])),
        shape=(rows.count, system.dofs),
    )
    g = sp.csr_matrix(picks @ system.transform)
    reduced, forces = solve_obstacle(system.reduced_stiffness, g, system.reduce(f), rows.surface)
    u = system.expand(reduced)
    w = np.asarray(picks @ u)
    readings = tool_readings(checked, rows, forces, w)  # per row: w, forces, surface, owner
    return Pressed(u, rows.coordinates, rows.surface, rows.owner, forces, readings)


def _value_nodes(system: System) -> tuple[IntArray, FloatArray]:
    """The DOFs that are values of w at a vertex, and the vertices (vertices, 2) (m)."""
    dofs = np.asarray(system.basis.nodal_dofs[0], dtype=np.intp)
    return dofs, np.ascontiguousarray(system.domain.mesh.p.T)


def solve_obstacle(
    k: sp.spmatrix, g: sp.csr_matrix, f: FloatArray, surface: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """r and lambda of the obstacle problem (module docstring)."""
    free = splu(sp.csc_matrix(k)).solve(f)  # also the answer whenever no node is held
    rows = surface.size
    if rows == 0:
        return free, np.zeros(0)
    gap_tol = _TOLERANCE * max(float(np.abs(surface).max()), float(np.abs(g @ free).max()))
    active = g @ free > surface
    seen: set[bytes] = set()
    single = False
    for _ in range(4 * rows + 64):  # single flips end for K positive definite: a guard
        r, force = _held(k, g, f, surface, active, free)
        force_tol = _TOLERANCE * float(np.abs(force).max(initial=0.0))
        wrong = (active & (force < -force_tol)) | (~active & (g @ r - surface > gap_tol))
        if not wrong.any():
            return r, np.maximum(force, 0.0)
        key = np.packbits(active).tobytes()
        single = single or key in seen  # a cycle (K not an M-matrix): Murty's rule from now
        seen.add(key)
        if single:
            first = int(np.flatnonzero(wrong)[0])
            active[first] = not active[first]
        else:
            active ^= wrong
    raise RuntimeError(f"the static contact did not converge ({rows} nodes)")


def _held(
    k: sp.spmatrix,
    g: sp.csr_matrix,
    f: FloatArray,
    surface: FloatArray,
    active: NDArray[np.bool_],
    free: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """r with the ``active`` nodes held on the surface, and their forces (0 elsewhere):
    [[K, G_a'], [G_a, 0]] [r, lambda_a] = [f, s_a] (``free``: K^-1 f, r when none is)."""
    chosen = np.flatnonzero(active)
    force = np.zeros(surface.size)
    if chosen.size == 0:
        return free, force
    g_a = g[chosen]
    saddle = sp.bmat([[k, g_a.T], [g_a, None]], format="csc")
    try:
        solved = splu(saddle).solve(np.concatenate([f, surface[chosen]]))
    except RuntimeError:  # SuperLU: singular, a held node no DOF moves
        raise InvalidSolve(
            "a tool presses below the rest surface where the tissue cannot move"
        ) from None
    n = k.shape[0]
    force[chosen] = solved[n:]
    return solved[:n], force


def _load(system: System, load: ArrayLike | None) -> FloatArray:
    if load is None:
        return np.zeros(system.dofs)
    f = np.asarray(load, dtype=np.float64)
    if f.shape != (system.dofs,) or not np.isfinite(f).all():
        raise InvalidLoad(f"a load is {system.dofs} finite values (the DOFs), not {f.shape}")
    return f
