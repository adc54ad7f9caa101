"""The reduced von Karman plate in time and at rest: Newton in r coordinates, rigid tools exact.

The step is the discrete-gradient (energy-consistent) scheme of the reduced plate
(``reduced_plate``): with q0, v0 at the start and q1, v1 at the end of a step of dt,

    (q1 - q0) / dt = (v0 + v1) / 2,
    (v1 - v0) / dt = -D (v0 + v1) / 2 - Omega^2 (q0 + q1) / 2 - g(q0, q1) - P' lambda,
    g(q0, q1) = 2 H((Q0 + Q1) / 2) (q0 + q1) / 2,   H(Q)_ik = sum_lm G_iklm Q_lm,  Q = q q',

D = diag(2 zeta omega), P the basis at the tools' lattice points and lambda >= 0 their forces
(N, pressing along -z), held over the step. g is a discrete gradient of the stretching energy
(g . (q1 - q0) = V_s(q1) - V_s(q0) exactly), and the linear part is the trapezoidal rule, so
without damping or contact the energy 1/2 |v|^2 + 1/2 sum omega^2 q^2 + V_s(q) is conserved to
Newton's tolerance whatever dt: the implicit midpoint rule or Newmark conserve a quartic energy
only approximately. It is second order, and unconditionally stable.

The tools' contact is solved inside Newton: at each iterate q (Jacobian J, residual F) the
points' displacement at the end of the step is z = P (q - J^-1 F) - C lambda with
C = P J^-1 P' + R_pp (``reduced_plate``'s residual: the linear static response of what the
basis does not carry), and lambda solves the complementarity problem of z <= the tools'
surface (``live.contact.solve_points``; J is not symmetric, C a P-matrix near a stable state).
The static press is the same iteration without inertia.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg.lapack
from numpy.typing import NDArray

from membrane_models.fem.reduced_plate import ReducedPlate
from membrane_models.live.contact import solve_points

__all__ = [
    "IterationMatrix",
    "NotConverged",
    "Solved",
    "StepCoefficients",
    "press_reduced",
    "step_reduced",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
MAX_ITERATIONS = 30
_TOLERANCE = 1e-11  # relative change of q at which Newton stops
_REFRESH = 3  # iterations between two factorisations of the Jacobian
_CONTACT_TOLERANCE = 1e-12  # a gap that counts as closed, relative to the largest violation


class NotConverged(RuntimeError):
    """Newton did not converge within ``MAX_ITERATIONS`` (a step far past moderate rotations)."""


@dataclass(frozen=True)
class StepCoefficients:
    """What a step of ``dt`` adds to the Jacobian's diagonal: 2 / dt^2 + 2 zeta omega / dt +
    omega^2 / 2, and the damping's D."""

    dt: float
    damping: FloatArray
    diagonal: FloatArray

    @classmethod
    def of(cls, plate: ReducedPlate, dt: float, zeta: float | FloatArray) -> StepCoefficients:
        damping = np.broadcast_to(2.0 * np.asarray(zeta) * plate.omega, plate.omega.shape)
        diagonal = 2.0 / dt**2 + damping / dt + 0.5 * plate.omega**2
        return cls(dt, np.asarray(damping, dtype=np.float64), np.asarray(diagonal))


@dataclass(frozen=True)
class Solved:
    """A step's (or a press's) end: q, v (zero at rest), the points' forces and displacements,
    the Newton iterations spent and the iteration matrix last used."""

    q: FloatArray
    v: FloatArray
    forces: FloatArray
    displacement: FloatArray
    iterations: int
    matrix: IterationMatrix


def step_reduced(
    plate: ReducedPlate,
    coefficients: StepCoefficients,
    q0: FloatArray,
    v0: FloatArray,
    points: IntArray,
    surface: FloatArray,
    load: FloatArray | None = None,
    start: NDArray[np.bool_] | None = None,
    matrix: IterationMatrix | None = None,
    acceleration: FloatArray | None = None,
) -> Solved:
    """One step from (q0, v0) with the tools' lattice ``points`` kept at or below ``surface``
    (m), under an optional modal ``load`` held over the step (module docstring); ``start``:
    the points in contact at the last step, where the contact's search begins; ``matrix``:
    the last step's iteration matrix (``Solved.matrix``), Newton's first; ``acceleration``:
    the last step's mean acceleration, for Newton's first guess q0 + dt v0 + dt^2 a / 2.

    Raises:
        NotConverged: Newton did not converge.
    """
    dt = coefficients.dt
    r = plate.size
    start_pairs = plate.pair_products(q0)
    guess = q0 + dt * v0
    if acceleration is not None:
        guess += (0.5 * dt * dt) * acceleration
    linear_rhs = (2.0 / dt**2) * (q0 + dt * v0) + (coefficients.damping / dt) * q0
    linear_rhs -= 0.5 * plate.omega**2 * q0
    if load is not None:
        linear_rhs = linear_rhs + load

    def residual(q1: FloatArray) -> FloatArray:
        h = plate.contracted(0.5 * (start_pairs + plate.pair_products(q1)))
        return np.asarray(coefficients.diagonal * q1 - linear_rhs + h @ (q0 + q1))

    def jacobian(q1: FloatArray) -> FloatArray:
        middle = 0.5 * (q0 + q1)
        h = plate.contracted(0.5 * (start_pairs + plate.pair_products(q1)))
        crossed = (plate.crossed_matrix @ np.outer(middle, q1).ravel()).reshape(r, r)
        tangent = h + 2.0 * crossed
        tangent.flat[:: r + 1] += coefficients.diagonal
        return np.asarray(tangent)

    q, forces, displacement, iterations, used = _newton(
        plate, residual, jacobian, guess, points, surface, active=start, matrix=matrix
    )
    v = 2.0 * (q - q0) / dt - v0
    return Solved(q, v, forces, displacement, iterations, used)


def press_reduced(
    plate: ReducedPlate,
    points: IntArray,
    surface: FloatArray,
    start: FloatArray | None = None,
    load: FloatArray | None = None,
) -> Solved:
    """The static state with the lattice ``points`` at or below ``surface`` (m), from the
    guess ``start`` (default: at rest), under an optional modal ``load`` (N per unit q).

    Raises:
        NotConverged: Newton did not converge (press in smaller increments).
    """
    r = plate.size
    stiffness = plate.omega**2
    external = np.zeros(r) if load is None else load

    def residual(q: FloatArray) -> FloatArray:
        return np.asarray(stiffness * q + plate.stretching_force(q) - external)

    def jacobian(q: FloatArray) -> FloatArray:
        h = plate.contracted(plate.pair_products(q))
        tangent = 2.0 * h + 4.0 * (plate.crossed_matrix @ np.outer(q, q).ravel()).reshape(r, r)
        tangent.flat[:: r + 1] += stiffness
        return np.asarray(tangent)

    guess = np.zeros(r) if start is None else np.asarray(start, dtype=np.float64)
    q, forces, displacement, iterations, used = _newton(
        plate, residual, jacobian, guess, points, surface, refresh=1
    )
    return Solved(q, np.zeros(r), forces, displacement, iterations, used)


@dataclass(frozen=True, eq=False)
class IterationMatrix:
    """A factored Jacobian and what it gives the tools' points: the iteration matrix of the
    next step's Newton (a chord iteration; a step's Jacobian changes little from the last)."""

    lu: FloatArray
    pivots: NDArray[np.int32]
    points: IntArray
    response: FloatArray  # J^-1 P'
    compliance: FloatArray  # P J^-1 P' + R_pp

    @classmethod
    def of(cls, plate: ReducedPlate, jacobian: FloatArray, points: IntArray) -> IterationMatrix:
        lu, pivots = _factor(jacobian)
        return cls(lu, pivots, points, *_point_response(plate, (lu, pivots), points))

    def at(self, plate: ReducedPlate, points: IntArray) -> IterationMatrix:
        """The same matrix for another set of points."""
        if np.array_equal(points, self.points):
            return self
        factor = (self.lu, self.pivots)
        return IterationMatrix(self.lu, self.pivots, points, *_point_response(plate, factor,
                               points))  # fmt: skip


def _point_response(
    plate: ReducedPlate, factor: tuple[FloatArray, NDArray[np.int32]], points: IntArray
) -> tuple[FloatArray, FloatArray]:
    shapes = plate.shapes[points]
    if not points.size:
        return np.zeros((plate.size, 0)), np.zeros((0, 0))
    response = _solve(factor, np.ascontiguousarray(shapes.T))
    return response, shapes @ response + plate.residual[np.ix_(points, points)]


def _newton(
    plate: ReducedPlate,
    residual: Callable[[FloatArray], FloatArray],
    jacobian: Callable[[FloatArray], FloatArray],
    q: FloatArray,
    points: IntArray,
    surface: FloatArray,
    refresh: int = _REFRESH,
    active: NDArray[np.bool_] | None = None,
    matrix: IterationMatrix | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, int, IterationMatrix]:
    """Newton with the points' contact solved at every iterate (module docstring): q, the
    points' forces, their displacements (with the residual's share), the iterations and the
    iteration matrix last used.

    A chord iteration: the Jacobian (or the last step's ``matrix``) is factored once and
    refreshed at the current iterate every ``refresh`` iterations. The residual is always
    exact, so the answer is Newton's; only the rate of convergence depends on the matrix."""
    shapes = plate.shapes[points]  # (p, r)
    forces = np.zeros(points.size)
    scale = max(float(np.abs(q).max()), 1e-300)
    chosen = None if active is None else np.flatnonzero(active)
    current = None if matrix is None else matrix.at(plate, points)
    contact = None if current is None else _Contact(current.compliance, chosen)
    for iteration in range(1, MAX_ITERATIONS + 1):
        if current is None or contact is None or (iteration > 1 and (iteration - 1) % refresh == 0):
            current = IterationMatrix.of(plate, jacobian(q), points)
            contact = _Contact(current.compliance, chosen if contact is None else contact.chosen)
        shift = _solve((current.lu, current.pivots), residual(q))
        if points.size:
            free = shapes @ (q - shift)
            forces = contact.forces(free - surface)
            step = shift + current.response @ forces
        else:
            step = shift
        q = q - step
        change = float(np.abs(step).max())
        if not math.isfinite(change):
            break
        if change <= _TOLERANCE * max(scale, float(np.abs(q).max())):
            flexibility = current.compliance - shapes @ current.response
            displacement = shapes @ q - flexibility @ forces
            return q, forces, displacement, iteration, current
    raise NotConverged(f"Newton did not converge in {MAX_ITERATIONS} iterations")


def _factor(matrix: FloatArray) -> tuple[FloatArray, NDArray[np.int32]]:
    """LAPACK's LU of a small dense matrix (scipy's wrappers cost more than the work here)."""
    lu, pivots, info = _GETRF(matrix, overwrite_a=True)
    if info != 0:
        raise NotConverged("the step's Jacobian is singular")
    return lu, pivots


def _solve(factor: tuple[FloatArray, NDArray[np.int32]], rhs: FloatArray) -> FloatArray:
    solution, info = _GETRS(factor[0], factor[1], rhs)
    assert info == 0
    return np.asarray(solution)


class _Contact:
    """The points' forces for one iteration matrix: the last solve's active set tried first
    (usually still right), its block's LU kept while the set stays; else ``solve_points``
    from it."""

    def __init__(self, compliance: FloatArray, chosen: IntArray | None) -> None:
        self.compliance = compliance
        self.chosen = chosen  # the active set to try first (None: the violated points)
        self._factor: tuple[FloatArray, NDArray[np.int32]] | None = None

    def forces(self, violation: FloatArray) -> FloatArray:
        c = self.compliance
        chosen = np.flatnonzero(violation > 0.0) if self.chosen is None else self.chosen
        if chosen.size:
            if self._factor is None:
                lu, pivots, info = _GETRF(c[chosen][:, chosen])
                self._factor = (lu, pivots) if info == 0 else None
            if self._factor is not None:
                forces = np.zeros(violation.size)
                forces[chosen] = _GETRS(*self._factor, violation[chosen])[0]
                gap = c @ forces - violation
                gap[chosen] = 0.0
                tolerance = _CONTACT_TOLERANCE * float(np.abs(violation).max())
                if forces.min() >= 0.0 and gap.min() >= -tolerance:
                    self.chosen = chosen
                    return forces
        start = None
        if self.chosen is not None:
            start = np.zeros(violation.size, dtype=bool)
            start[self.chosen] = True
        forces = solve_points(c, violation, start)
        self.chosen, self._factor = np.flatnonzero(forces > 0.0), None
        return forces


_GETRF, _GETRS = scipy.linalg.lapack.get_lapack_funcs(("getrf", "getrs"), dtype=np.float64)
