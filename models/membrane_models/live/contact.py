"""Unilateral contact of rigid probes, solved exactly for one step.

With the contact forces F (>= 0, pressing along -axis) held over the step, the footprint-
weighted displacements at its end are z = z_free - C F, where z_free is the end-of-step response
without contact and C the one-step compliance matrix (symmetric, positive semi-definite: a Gram
matrix of the footprints' modal forces). A probe of depth d keeps z <= -d and may only push:

    gap y = C F - b >= 0,   F >= 0,   F . y = 0,   with b = z_free + d,

a linear complementarity problem. One probe: F = max(0, b / c). Several probes couple through
their cross-compliances: for a positive definite C (a P-matrix) Murty's least-index principal
pivoting finds the unique solution in finitely many pivots; for a singular C (two probes on the
same footprint) every active set is tried, smallest first (at most 2^8 for 8 probes). No penalty
stiffness anywhere: stable at any stiffness, the constraint-based rendering of SOFA's haptics.

Grasps are bilateral: C F = b exactly on their rows, F of either sign. With E the grasps' rows
and U the probes', F_E = C_EE^-1 (b_E - C_EU F_U), and F_U solves the probes' problem on the
Schur complement C_UU - C_UE C_EE^-1 C_EU (positive definite when C is) with b_U - C_UE
C_EE^-1 b_E: the mixed problem exactly, by the same solver.

A rigid tool's rows are lattice points, each pushed by a small footprint (``tools``): the
displacement at a point per unit force on another point's footprint is not quite the reverse
(a point and a footprint are not the same readout), so C is not symmetric, but it is a P-matrix
(its symmetric part is the positive definite Gram matrix of the footprints, up to the
footprints' width). ``solve_points`` solves that problem by block principal pivoting (Judice and
Pires 1994: flip every infeasible row while their number falls, else one row by Murty's least
index rule), finite for P-matrices and a few pivots in practice, from the guess that every
point the free tissue crosses is in contact.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.errors import InvalidGrasp, InvalidProbe

__all__ = ["single_contact", "solve_contact", "solve_mixed", "solve_points"]

FloatArray = NDArray[np.float64]

_TOLERANCE = 1e-12  # relative to the largest violation: what counts as zero in the checks
_BLOCK_TRIES = 3  # block pivots allowed without fewer infeasible rows before single pivots


def solve_contact(compliance: FloatArray, violation: FloatArray) -> FloatArray:
    """The contact forces F >= 0 with C F - b >= 0 and F . (C F - b) = 0.

    Args:
        compliance: C, shape (P, P), symmetric positive semi-definite.
        violation: b = z_free + depth, shape (P,): > 0 where the free tissue would cross the tip.

    Raises:
        InvalidProbe: no force can hold the tissue at the tips (a probe with zero compliance,
            on a clamped point, pressed below the rest surface).
    """
    c = np.asarray(compliance, dtype=np.float64)
    b = np.asarray(violation, dtype=np.float64)
    if b.size == 1:
        return np.array([single_contact(float(c[0, 0]), float(b[0]))])
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return _enumerate(c, b)
    return _murty(c, b)


def solve_mixed(
    compliance: FloatArray, violation: FloatArray, bilateral: NDArray[np.bool_]
) -> FloatArray:
    """``solve_contact`` where the rows ``bilateral`` marks are held exactly (grasps).

    Raises:
        InvalidGrasp: the grasps cannot be held (one on a clamped point, or two on one point:
            their compliance block is singular).
        InvalidProbe: as ``solve_contact``.
    """
    c = np.asarray(compliance, dtype=np.float64)
    b = np.asarray(violation, dtype=np.float64)
    held, free = np.flatnonzero(bilateral), np.flatnonzero(~bilateral)
    block = c[np.ix_(held, held)]
    if np.linalg.matrix_rank(block) < held.size or not np.diag(block).min() > 0.0:
        raise InvalidGrasp(
            "these grasps cannot be held: one sits where the tissue cannot move (a clamped "
            "point), or two hold one point"
        )
    coupling = c[np.ix_(free, held)]
    solve_held = np.linalg.solve(block, np.column_stack([b[held], coupling.T]))
    force = np.zeros(b.size)
    if free.size:
        schur = c[np.ix_(free, free)] - coupling @ solve_held[:, 1:]
        force[free] = solve_contact(0.5 * (schur + schur.T), b[free] - coupling @ solve_held[:, 0])
    force[held] = solve_held[:, 0] - solve_held[:, 1:] @ force[free]
    return force


def solve_points(
    compliance: FloatArray, violation: FloatArray, start: NDArray[np.bool_] | None = None
) -> FloatArray:
    """``solve_contact`` for a P-matrix C that need not be symmetric (a tool's points), from
    the active set ``start`` when given (a Newton iterate's last: often already the answer).

    Raises:
        InvalidProbe: no force can hold the tissue (a row of zero compliance pressed).
    """
    c = np.asarray(compliance, dtype=np.float64)
    b = np.asarray(violation, dtype=np.float64)
    n = b.size
    if n == 0 or not (b > 0.0).any():
        return np.zeros(n)
    if n == 1:
        return np.array([single_contact(float(c[0, 0]), float(b[0]))])
    if not np.diag(c).min() > 0.0:
        raise InvalidProbe("a tool's point cannot move (zero compliance): it cannot be pressed")
    gap_tol, force_tol = _tolerances(c, b)
    active = b > 0.0 if start is None else np.array(start, dtype=bool)
    fewest, tries = n + 1, _BLOCK_TRIES
    for _ in range(64 * n * n):  # Murty's pivots alone end for a P-matrix; this is a guard
        force = _forces(c, b, active)
        gap = c @ force - b
        bad = (active & (force < -force_tol)) | (~active & (gap < -gap_tol))
        count = int(bad.sum())
        if count == 0:
            return np.maximum(force, 0.0)
        if count < fewest:
            fewest, tries = count, _BLOCK_TRIES
        else:
            tries -= 1
        if tries > 0:
            active ^= bad
        else:
            last = int(np.flatnonzero(bad)[-1])
            active[last] = not active[last]
    raise RuntimeError(f"tool contact did not converge in {64 * n * n} pivots (n = {n})")


def single_contact(c: float, b: float) -> float:
    """One probe: F = max(0, b / c) for compliance c and violation b (see ``solve_contact``)."""
    if b <= 0.0:
        return 0.0
    if not c > 0.0:
        raise InvalidProbe(
            "the probe sits where the tissue cannot move (zero compliance, a clamped point): "
            "no force holds it below the rest surface; use depth 0 there"
        )
    return b / c


def _murty(c: FloatArray, b: FloatArray) -> FloatArray:
    """Least-index principal pivoting (Murty 1974): finite for P-matrices."""
    n = b.size
    gap_tol, force_tol = _tolerances(c, b)
    active = np.zeros(n, dtype=bool)
    for _ in range(2**n + 1):
        force = _forces(c, b, active)
        gap = c @ force - b
        bad = (active & (force < -force_tol)) | (~active & (gap < -gap_tol))
        if not bad.any():
            return np.maximum(force, 0.0)
        first = int(np.flatnonzero(bad)[0])
        active[first] = not active[first]
    return _enumerate(c, b)  # not reached for a P-matrix; kept as a safety net


def _enumerate(c: FloatArray, b: FloatArray) -> FloatArray:
    """Every active set, smallest first; least squares on singular blocks."""
    n = b.size
    gap_tol, force_tol = _tolerances(c, b)
    for size in range(n + 1):
        for chosen in itertools.combinations(range(n), size):
            active = np.zeros(n, dtype=bool)
            active[list(chosen)] = True
            force = _forces(c, b, active, least_squares=True)
            gap = c @ force - b
            if (
                (force >= -force_tol).all()
                and (gap >= -gap_tol).all()
                and np.abs(gap[active]).max(initial=0.0) <= gap_tol
            ):
                return np.maximum(force, 0.0)
    raise InvalidProbe(
        "the probes cannot be held at their depths by pushing alone (a probe on a clamped "
        "point pressed below the rest surface)"
    )


def _forces(
    c: FloatArray, b: FloatArray, active: NDArray[np.bool_], least_squares: bool = False
) -> FloatArray:
    """F with C_aa F_a = b_a on the active set a, 0 elsewhere."""
    force = np.zeros(b.size)
    if active.any():
        block, rhs = c[np.ix_(active, active)], b[active]
        if least_squares:
            force[active] = np.linalg.lstsq(block, rhs, rcond=None)[0]
        else:
            force[active] = np.linalg.solve(block, rhs)
    return force


def _tolerances(c: FloatArray, b: FloatArray) -> tuple[float, float]:
    """What counts as zero: a gap (a displacement), and a force (through the compliance)."""
    gap = _TOLERANCE * float(np.abs(b).max()) + 1e-300
    return gap, gap / max(float(np.diag(c).max()), 1e-300)
