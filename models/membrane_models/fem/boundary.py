"""Boundary conditions per part, turned into the constrained space u = T r.

A condition is set per boundary part: "clamped", "simply_supported" or "free" (a part not
named is free). Every constraint is homogeneous and local, so the admissible vectors are
``u = transform @ r``: free DOFs pass through, a constrained vertex's six Argyris DOFs are
replaced by a basis of what its constraints leave free, a fixed DOF is dropped.

The plate (Argyris: vertex w, w_x, w_y, w_xx, w_xy, w_yy; edge-midpoint normal derivative).
At a boundary vertex, with the edge's tangent t, outward normal n and curvature kappa
(``geometry``'s conventions), along the edge

    d w / ds = t . grad w,   d2 w / ds2 = t' H t - kappa n . grad w,
    d (n . grad w) / ds = n' H t + kappa t . grad w,

and the conditions hold along the edge, so the vertex gets

- simply supported: w = 0, d w/ds = 0, d2 w/ds2 = 0 (the normal slope is free);
- clamped: those and n . grad w = 0, d(n . grad w)/ds = 0 (only w_nn is free); the edge's
  midpoint normal derivative is fixed.

A vertex on several edges gets the union (a square's simply supported corner keeps only
w_xy). On a straight part the frame is the facet's own (kappa = 0), and w then vanishes along
the whole edge. On a curved part the frame is the exact curve's at the vertex
(``exact_frame=True``, the default): in the polygon's frame instead, a simply supported vertex
between two chords gets grad w = 0, and the disk converges to another plate, nearly the clamped
one (Babuska's paradox); ``exact_frame=False`` is kept to show it.

The membrane (P2) and the Morley plate: a clamped or simply supported part fixes its vertex
values (and the membrane's edge values; Morley's clamped part its edge normal derivatives).

Before anything is solved, the constraints are checked against the rigid-body motions the
model's energy does not see (a plate without foundation: w = a + b x + c y, or only constants
under pre-tension; a membrane: constants): if one survives, ``RigidBodyModes``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, cast, get_args

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from membrane_models.fem.errors import InvalidSupports, RigidBodyModes
from membrane_models.fem.geometry import Domain

__all__ = [
    "CONDITIONS",
    "Condition",
    "Constraints",
    "constrain",
    "resolve_parts",
    "resolve_supports",
]

Condition = Literal["clamped", "simply_supported", "free"]
CONDITIONS: tuple[str, ...] = get_args(Condition)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
_ORDER = np.array([0, 1, 1, 2, 2, 2])  # derivative order of the Argyris vertex DOFs
_RANK_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class Constraints:
    """The constrained space.

    Attributes:
        transform: T, sparse ``(N, n)``: every admissible DOF vector is ``T @ r``.
        fixed: how many independent constraints there are (N - n).
    """

    transform: sp.csr_matrix
    fixed: int


def resolve_supports(domain: Domain, supports: Mapping[str, str] | str) -> dict[str, Condition]:
    """Part -> condition, checked: one condition for every part, or a mapping of some."""
    return cast(dict[str, Condition], resolve_parts(domain, supports, CONDITIONS, "condition"))


def resolve_parts(
    domain: Domain, conditions: Mapping[str, str] | str, known: tuple[str, ...], what: str
) -> dict[str, str]:
    """Part -> one of ``known``, checked against the domain's parts (``what`` names the kind
    of condition in messages): one condition for every part, or a mapping of some."""
    if isinstance(conditions, str):
        conditions = dict.fromkeys(domain.parts, conditions)
    resolved: dict[str, str] = {}
    for part, condition in conditions.items():
        if part not in domain.parts:
            raise InvalidSupports(f"no boundary part {part!r} (parts: {', '.join(domain.parts)})")
        if condition not in known:
            raise InvalidSupports(
                f"unknown {what} {condition!r} on {part!r} (conditions: {', '.join(known)})"
            )
        resolved[part] = condition
    return resolved


def constrain(
    domain: Domain,
    basis: Any,
    element: str,
    supports: Mapping[str, Condition],
    exact_frame: bool = True,
    motions: int = 3,
    what: str = "plate",
) -> Constraints:
    """The constrained space of ``basis`` (its element named ``element``: "argyris", "morley"
    "p1" or "p2") under ``supports``; ``motions`` rigid motions to refuse (0, 1: constants, 3:
    affine). Raises ``RigidBodyModes`` if one survives the constraints."""
    mesh = domain.mesh
    held = {p: c for p, c in supports.items() if c != "free"}
    facets = {p: domain.parts[p] for p in held}
    center = mesh.p.mean(axis=1, keepdims=True)
    extent = float(np.ptp(mesh.p, axis=1).max())
    scaled = (mesh.p - center) / extent  # coordinates of the rigid-motion check
    checks: list[FloatArray] = []  # each constraint on the rigid motions (1, X, Y)
    fixed: list[IntArray] = []
    if element == "argyris":
        transform, count, rows, blocked = _argyris(domain, basis, held, facets, exact_frame, scaled)
        checks.append(rows)
        fixed.append(blocked)
        clamped = _concat([facets[p] for p, c in held.items() if c == "clamped"])
        fixed.append(basis.facet_dofs[0, clamped])
        checks.append(np.column_stack([np.zeros(clamped.size), *_normals(mesh, clamped)]))
    else:
        transform, count = None, 0
        every = _concat(list(facets.values()))
        vertices = np.unique(mesh.facets[:, every])
        fixed.append(basis.nodal_dofs[0, vertices])
        checks.append(np.column_stack([np.ones(vertices.size), scaled[:, vertices].T]))
        if element == "p2":
            fixed.append(basis.facet_dofs[0, every])
            middle = 0.5 * (scaled[:, mesh.facets[0, every]] + scaled[:, mesh.facets[1, every]])
            checks.append(np.column_stack([np.ones(every.size), middle.T]))
        elif element == "morley":  # a clamped edge's normal derivative
            clamped = _concat([facets[p] for p, c in held.items() if c == "clamped"])
            fixed.append(basis.facet_dofs[0, clamped])
            checks.append(np.column_stack([np.zeros(clamped.size), *_normals(mesh, clamped)]))
    _refuse_rigid(np.concatenate(checks)[:, :motions], motions, what)
    return _assemble_transform(basis.N, transform, count, np.concatenate(fixed))


def _argyris(
    domain: Domain,
    basis: Any,
    held: Mapping[str, Condition],
    facets: Mapping[str, IntArray],
    exact_frame: bool,
    scaled: FloatArray,
) -> tuple[tuple[IntArray, IntArray, FloatArray], int, FloatArray, IntArray]:
    """The vertex blocks of T (rows, local columns, values; their column count), the rigid
    checks, and every DOF of the constrained vertices (none of them passes through)."""
    mesh = domain.mesh
    vertex_ids: list[IntArray] = []
    row_blocks: list[FloatArray] = []
    for part, condition in held.items():
        ids = facets[part]
        ends = mesh.facets[:, ids]  # (2, f)
        chord = mesh.p[:, ends[1]] - mesh.p[:, ends[0]]
        chord /= np.linalg.norm(chord, axis=0)
        for end in (0, 1):
            vertices = ends[end]
            curve = domain.curves.get(part) if exact_frame else None
            if curve is None:
                tangent, curvature = chord, np.zeros(ids.size)
                normal = np.stack([tangent[1], -tangent[0]])
            else:
                frame = curve.frame(mesh.p[:, vertices])
                normal, tangent, curvature = frame.normal, frame.tangent, frame.curvature
            block = _vertex_rows(tangent, normal, curvature, condition)  # (f, k, 6)
            vertex_ids.append(np.repeat(vertices, block.shape[1]))
            row_blocks.append(block.reshape(-1, 6))
    if not vertex_ids:
        none = np.zeros(0, np.int64)
        return (none, none, np.zeros(0)), 0, np.zeros((0, 3)), none
    vertex = np.concatenate(vertex_ids)
    rows = np.concatenate(row_blocks)
    # rigid-motion checks: rows in DOFs scaled by the extent, against (1, X, Y)
    extent = float(np.ptp(mesh.p, axis=1).max())
    check_rows = _unit_rows(rows / extent ** _ORDER[None, :])
    motion = np.zeros((vertex.size, 6, 3))
    motion[:, 0, 0] = 1.0
    motion[:, 0, 1:] = scaled[:, vertex].T
    motion[:, 1, 1] = motion[:, 2, 2] = 1.0
    checks = np.einsum("rj,rjm->rm", check_rows, motion)
    # the null space of each vertex's rows, in DOFs scaled by the element size
    size = domain.size
    local = _unit_rows(rows / size ** _ORDER[None, :])
    order = np.argsort(vertex, kind="stable")
    vertex, local = vertex[order], local[order]
    unique, first, counts = np.unique(vertex, return_index=True, return_counts=True)
    slot = np.arange(vertex.size) - np.repeat(first, counts)
    stacked = np.zeros((unique.size, max(6, int(counts.max())), 6))
    stacked[np.repeat(np.arange(unique.size), counts), slot] = local
    _, singular, vh = np.linalg.svd(stacked, full_matrices=True)
    rank = (singular[:, :6] > _RANK_TOL * singular[:, :1]).sum(axis=1)
    keep = np.arange(6)[None, :] >= rank[:, None]  # (v, 6): which right singular vectors
    which_vertex, which_vector = np.nonzero(keep)
    basis_vectors = vh[which_vertex, which_vector] / size ** _ORDER[None, :]  # physical DOFs
    column = np.repeat(np.arange(which_vertex.size), 6)
    dof = basis.nodal_dofs[:, unique[which_vertex]].T.ravel()
    values = basis_vectors.ravel()
    small = np.abs(values) > 1e-14 * np.abs(values).max(initial=1.0)
    blocked = basis.nodal_dofs[:, unique].ravel()
    return (dof[small], column[small], values[small]), int(which_vertex.size), checks, blocked


def _vertex_rows(
    tangent: FloatArray, normal: FloatArray, curvature: FloatArray, condition: Condition
) -> FloatArray:
    """The constraint rows ``(f, k, 6)`` on (w, w_x, w_y, w_xx, w_xy, w_yy) (module docstring)."""
    tx, ty = tangent
    nx, ny = normal
    zero, one = np.zeros_like(tx), np.ones_like(tx)
    kappa = curvature
    rows = [
        [one, zero, zero, zero, zero, zero],  # w
        [zero, tx, ty, zero, zero, zero],  # dw/ds
        [zero, -kappa * nx, -kappa * ny, tx * tx, 2 * tx * ty, ty * ty],  # d2w/ds2
    ]
    if condition == "clamped":
        rows += [
            [zero, nx, ny, zero, zero, zero],  # dw/dn
            [zero, kappa * tx, kappa * ty, tx * nx, tx * ny + ty * nx, ty * ny],  # d(dw/dn)/ds
        ]
    return np.moveaxis(np.array(rows, dtype=np.float64), -1, 0)


def _refuse_rigid(checks: FloatArray, motions: int, what: str) -> None:
    """``RigidBodyModes`` unless the constraints' values on the motions have full rank."""
    if motions == 0:
        return
    if checks.shape[0] == 0:
        free = motions
    else:
        singular = np.linalg.svd(checks, compute_uv=False)
        free = motions - int((singular > _RANK_TOL * max(singular[0], 1.0)).sum())
    if free > 0:
        form = "w = a" if motions == 1 else "w = a + b x + c y"
        raise RigidBodyModes(
            f"the supports leave the {what} {free} rigid-body motion{'s' if free > 1 else ''} "
            f"({form}): clamp or support more of the boundary"
            + (", or add a foundation" if what == "plate" else "")
        )


def _assemble_transform(
    total: int,
    vertex_blocks: tuple[IntArray, IntArray, FloatArray] | None,
    block_columns: int,
    fixed: IntArray,
) -> Constraints:
    constrained = np.zeros(total, dtype=bool)
    constrained[fixed] = True
    rows: list[IntArray] = []
    columns: list[IntArray] = []
    values: list[FloatArray] = []
    if vertex_blocks is not None and block_columns:
        dof, column, value = vertex_blocks
        constrained[dof] = True
        rows.append(dof)
        columns.append(column)
        values.append(value)
    free = np.flatnonzero(~constrained)
    rows.append(free)
    columns.append(block_columns + np.arange(free.size))
    values.append(np.ones(free.size))
    width = block_columns + free.size
    transform = sp.csr_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(columns))),
        shape=(total, width),
    )
    return Constraints(transform, total - width)


def _normals(mesh: Any, facets: IntArray) -> FloatArray:
    """Unit normals ``(2, f)`` of facets (sign arbitrary)."""
    chord = mesh.p[:, mesh.facets[1, facets]] - mesh.p[:, mesh.facets[0, facets]]
    chord = chord / np.maximum(np.linalg.norm(chord, axis=0), np.finfo(float).tiny)
    return np.stack([chord[1], -chord[0]])


def _unit_rows(rows: FloatArray) -> FloatArray:
    return rows / np.linalg.norm(rows, axis=1, keepdims=True)


def _concat(arrays: list[IntArray]) -> IntArray:
    return np.concatenate(arrays) if arrays else np.zeros(0, dtype=np.int64)
