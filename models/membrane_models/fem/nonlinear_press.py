"""Rigid tools pressed into the von Karman plate, solved on the full mesh: the reduced engine's
static reference.

The tool keeps w at or below its surface at chosen points (the live lattice's points under it,
``live.tools.tool_points``: the points the reduced engine constrains), each carrying a point
force >= 0 along -z. The press is taken in depth increments; at each, Newton on the coupled
von Karman tangent (``nonlinear.Equilibrium``) solves at every iterate the linearised obstacle
problem

    K_t d + G' lambda = -R(w, u),   G (w + d) <= s,   lambda >= 0,

by ``contact.solve_obstacle`` (the primal-dual active set), with G the rows sampling w at the
points (zero on u): semismooth Newton on the complementarity problem. Units: SI (m, N).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from membrane_models.fem.assembly import System
from membrane_models.fem.contact import solve_obstacle
from membrane_models.fem.errors import InvalidModel, InvalidSolve
from membrane_models.fem.models import Plate
from membrane_models.fem.nonlinear import Equilibrium
from membrane_models.fem.sampling import sampler
from membrane_models.fem.von_karman import residual, tangent

__all__ = ["NonlinearPress", "press_nonlinear"]

FloatArray = NDArray[np.float64]
_MAX_ITERATIONS = 40


@dataclass(frozen=True, eq=False)
class NonlinearPress:
    """One depth of a press: the state (w, u DOF vectors), the points' forces (N) and w there
    (m), and the Newton iterations it took."""

    w: FloatArray
    u: FloatArray
    forces: FloatArray
    displacement: FloatArray
    iterations: int

    @property
    def force(self) -> float:
        """The tool's total force (N)."""
        return float(self.forces.sum())


def press_nonlinear(
    system: System,
    points: FloatArray,
    surfaces: Sequence[FloatArray],
    inplane: Mapping[str, str] | str = "held",
    tolerance: float = 1e-10,
) -> list[NonlinearPress]:
    """The states with w at ``points`` (m, (p, 2)) at or below each of ``surfaces`` in turn
    (one height per point, m, along +z: a press's depths, each from the last's state).

    Raises:
        InvalidModel: not an Argyris plate.
        InvalidSolve: Newton did not converge at a depth (take smaller increments).
    """
    if not isinstance(system.model, Plate) or system.element != "argyris":
        raise InvalidModel("large deflections are solved on an Argyris plate (a Plate system)")
    problem = Equilibrium.of(system, inplane, sp.csr_matrix(system.stiffness))
    rows = sampler(system, points)
    g_w = sp.csr_matrix(rows @ system.transform)
    n_u = problem.free_u.size
    g = sp.hstack([g_w, sp.csr_matrix((g_w.shape[0], n_u))], format="csr")
    w, u = np.zeros(system.dofs), np.zeros(problem.inplane_basis.N)
    pressed = []
    for surface in surfaces:
        w, u, forces, spent = _press(system, problem, g, rows, w, u, surface, tolerance)
        pressed.append(NonlinearPress(w, u, forces, np.asarray(rows @ w), spent))
    return pressed


def _press(
    system: System,
    problem: Equilibrium,
    g: sp.csr_matrix,
    rows: sp.csr_matrix,
    w: FloatArray,
    u: FloatArray,
    surface: FloatArray,
    tolerance: float,
) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    t_w, pick = system.transform, problem.pick_u
    args = (system.basis, problem.inplane_basis)
    zero = np.zeros(system.dofs)
    a, nu = problem.stretching, problem.poisson
    scale = 1e-300
    for iteration in range(1, _MAX_ITERATIONS + 1):
        r_w, r_u = residual(*args, problem.bending, zero, w, u, a, nu)
        rhs = np.concatenate([system.reduce(r_w), pick.T @ r_u])
        k = tangent(*args, problem.bending, w, u, a, nu)
        matrix = sp.bmat(
            [
                [t_w.T @ k.ww @ t_w, t_w.T @ k.uw.T @ pick],
                [pick.T @ k.uw @ t_w, pick.T @ k.uu @ pick],
            ],
            format="csc",
        )
        step, forces = solve_obstacle(matrix, g, -rhs, surface - np.asarray(rows @ w))
        n_w = system.free
        w = w + system.expand(step[:n_w])
        u = u + pick @ step[n_w:]
        scale = max(scale, float(np.abs(w).max()))
        change = float(np.abs(system.expand(step[:n_w])).max())
        if not math.isfinite(change):
            break
        if change <= tolerance * scale:
            return w, u, forces, iteration
    raise InvalidSolve("the nonlinear press did not converge: take smaller depth increments")
