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

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg.lapack
from numpy.typing import NDArray

from membrane_models.fem.reduced_kernel import CONVERGED, NOT_FINITE, REFRESH_DUE, Chord
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
# the compiled iteration's: its chord iterates cost about 10 us against about 200 for a fresh
# Jacobian (numpy), so it tries more of them before handing on for one
_COMPILED_REFRESH = 8
_CONTACT_TOLERANCE = 1e-12  # a gap that counts as closed, relative to the largest violation


class NotConverged(RuntimeError):
    """Newton did not converge within ``MAX_ITERATIONS`` (a step far past moderate rotations)."""


@dataclass(frozen=True)
class StepCoefficients:
    """What a step of ``dt`` (s) on one plate needs besides its state, computed once: D =
    2 zeta omega (1/s), the Jacobian's diagonal 2 / dt^2 + D / dt + omega^2 / 2 and the weight
    2 / dt^2 + 2 D / dt (1/s^2) of q0 in the step's known side (``step_reduced``), and the
    diagonal on the plate's pairs (``ReducedPlate.pairs``: 0 off the pairs (i, i))."""

    dt: float
    damping: FloatArray
    diagonal: FloatArray
    lagging: FloatArray
    pair_diagonal: FloatArray

    @classmethod
    def of(cls, plate: ReducedPlate, dt: float, zeta: float | FloatArray) -> StepCoefficients:
        damping = np.broadcast_to(2.0 * np.asarray(zeta) * plate.omega, plate.omega.shape)
        diagonal = 2.0 / dt**2 + damping / dt + 0.5 * plate.omega**2
        lagging = 2.0 / dt**2 + 2.0 * damping / dt
        every = np.arange(plate.size)
        pair_diagonal = np.zeros(plate.pairs[0].size)
        pair_diagonal[plate.pairs[2][every, every]] = diagonal
        return cls(dt, np.asarray(damping, dtype=np.float64), np.asarray(diagonal),
                   np.asarray(lagging), pair_diagonal)  # fmt: skip


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
    chord: Chord | None = None,
) -> Solved:
    """One step from (q0, v0) with the tools' lattice ``points`` kept at or below ``surface``
    (m), under an optional modal ``load`` held over the step (module docstring); ``start``:
    the points in contact at the last step, where the contact's search begins; ``matrix``:
    the last step's iteration matrix (``Solved.matrix``), Newton's first; ``acceleration``:
    the last step's mean acceleration, for Newton's first guess q0 + dt v0 + dt^2 a / 2;
    ``chord``: the compiled iteration (``reduced_kernel.compiled_chord``), which takes the step
    where the last step's matrix and active set hold (else the numpy path below does).

    The residual is the module's second line times 2 / dt with v1 eliminated, written on
    s = q0 + q1 so that an iterate costs one product with G and one with H:

        F(q1) = (H((Q0 + Q1) / 2) + diag(d)) s - (2 / dt^2 (q0 + dt v0) + l q0 + load),

    d the Jacobian's diagonal and l = 2 / dt^2 + 2 D / dt (``StepCoefficients``).

    Raises:
        NotConverged: Newton did not converge.
    """
    resumed: tuple[FloatArray, int, bool] | None = None
    if chord is not None and matrix is not None:
        compiled = _compiled_step(chord, plate, coefficients, q0, v0, points, surface, load,
                                  start, matrix, acceleration)  # fmt: skip
        if isinstance(compiled, Solved):
            return compiled
        resumed = compiled
    dt = coefficients.dt
    r = plate.size
    first, second, index = plate.pairs
    packed, pair_diagonal = plate.pairs_matrix, coefficients.pair_diagonal
    diagonal = coefficients.diagonal
    start_pairs = q0[first] * q0[second]
    ahead = q0 + dt * v0
    guess = ahead if acceleration is None else ahead + (0.5 * dt * dt) * acceleration
    known = (2.0 / dt**2) * ahead
    known += coefficients.lagging * q0
    if load is not None:
        known += load

    def residual(q1: FloatArray) -> FloatArray:
        pairs = q1[first] * q1[second]
        pairs += start_pairs
        pairs *= 0.5
        mean = packed @ pairs  # H((Q0 + Q1) / 2) on the pairs
        mean += pair_diagonal
        f = mean[index] @ (q0 + q1)
        f -= known
        return np.asarray(f)

    def jacobian(q1: FloatArray) -> FloatArray:
        middle = 0.5 * (q0 + q1)
        h = (packed @ (0.5 * (start_pairs + q1[first] * q1[second])))[index]
        crossed = (plate.crossed_matrix @ np.outer(middle, q1).ravel()).reshape(r, r)
        tangent = h + 2.0 * crossed
        tangent.flat[:: r + 1] += diagonal
        return np.asarray(tangent)

    bound = _TOLERANCE * max(float(np.abs(guess).max()), 1e-300)
    resume_at = 1
    if resumed is not None:
        guess, resume_at, refresh_now = resumed
        matrix = None if refresh_now else matrix
    q, forces, displacement, iterations, used = _newton(
        plate, residual, jacobian, guess, points, surface, active=start, matrix=matrix,
        first=resume_at, bound=bound,
    )  # fmt: skip
    v = q - q0
    v *= 2.0 / dt
    v -= v0
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
    next step's Newton (a chord iteration; a step's Jacobian changes little from the last).

    Besides its fields it keeps, once asked, the points' flexibility and the last active
    set's contact solution (``solution``): a press keeps one matrix and one set for many
    steps."""

    lu: FloatArray
    pivots: NDArray[np.int32]
    points: IntArray
    shapes: FloatArray  # P, the basis at the points (p, r), m per unit q
    response: FloatArray  # J^-1 P'
    compliance: FloatArray  # P J^-1 P' + R_pp
    _solutions: dict[bytes, FloatArray | None] = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, plate: ReducedPlate, jacobian: FloatArray, points: IntArray) -> IterationMatrix:
        lu, pivots = _factor(jacobian)
        return cls(lu, pivots, points, *_point_response(plate, (lu, pivots), points))

    def at(self, plate: ReducedPlate, points: IntArray) -> IterationMatrix:
        """The same matrix for another set of points."""
        if points is self.points or np.array_equal(points, self.points):
            return self
        factor = (self.lu, self.pivots)
        return IterationMatrix(self.lu, self.pivots, points, *_point_response(plate, factor,
                               points))  # fmt: skip

    @functools.cached_property
    def contact_block(self) -> FloatArray:
        """P, (J^-1 P')' and the flexibility side by side, (p, 2 r + p): the compiled step's
        one array for the points (``reduced_kernel``)."""
        block = np.hstack([self.shapes, self.response.T, self.flexibility])
        block.setflags(write=False)
        return block

    @functools.cached_property
    def flexibility(self) -> FloatArray:
        """C - P J^-1 P' (m/N): the points' displacement per unit force beyond the basis's."""
        return np.asarray(self.compliance - self.shapes @ self.response)

    def solution(self, chosen: IntArray) -> FloatArray | None:
        """With the points ``chosen`` (A, a of the p) in contact and the others (B) not: the
        (2 p - a, p) matrix that takes the violation b to the forces F (F_A = C_AA^-1 b_A, 0
        on B) and then B's gaps C_BA F_A - b_B, in one product. None where C_AA is singular;
        kept for the last set asked."""
        key = chosen.tobytes()
        if key in self._solutions:
            return self._solutions[key]
        c = self.compliance
        count = c.shape[0]
        lu, pivots, info = _GETRF(c[np.ix_(chosen, chosen)])
        solution = None
        if info == 0:
            inverse, info = _GETRI(lu, pivots)
            rest = np.setdiff1d(np.arange(count), chosen)
            solution = np.zeros((2 * count - chosen.size, count))
            solution[np.ix_(chosen, chosen)] = inverse
            solution[count:, chosen] = c[np.ix_(rest, chosen)] @ inverse
            solution[count + np.arange(rest.size), rest] = -1.0
        self._solutions.clear()  # one set: the state's memory stays about the matrix's own
        self._solutions[key] = solution
        return solution


def _point_response(
    plate: ReducedPlate, factor: tuple[FloatArray, NDArray[np.int32]], points: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    shapes = plate.shapes[points]
    if not points.size:
        return shapes, np.zeros((plate.size, 0)), np.zeros((0, 0))
    response = _solve(factor, np.ascontiguousarray(shapes.T))
    return shapes, response, shapes @ response + plate.residual[np.ix_(points, points)]


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
    first: int = 1,
    bound: float | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, int, IterationMatrix]:
    """Newton with the points' contact solved at every iterate (module docstring): q, the
    points' forces, their displacements (with the residual's share), the iterations and the
    iteration matrix last used.

    A chord iteration: the Jacobian (or the last step's ``matrix``) is factored once and
    refreshed at the current iterate every ``refresh`` iterations. The residual is always
    exact, so the answer is Newton's; only the rate of convergence depends on the matrix.

    ``first``, ``bound``: where the compiled iteration stopped, its iterate given as ``q``
    (``reduced_kernel``), the iteration to go on from and the start's scale's bound."""
    forces = np.zeros(points.size)
    # |step| <= tol max(scale, |q|): tried on the start's scale first, |q| only when that fails
    if bound is None:
        bound = _TOLERANCE * max(float(np.abs(q).max()), 1e-300)
    chosen = None if active is None else active.nonzero()[0]
    current = None if matrix is None else matrix.at(plate, points)
    contact = None if current is None else _Contact(current, chosen)
    made_at = first  # the iteration the matrix in use was made at (or given at)
    for iteration in range(first, MAX_ITERATIONS + 1):
        if current is None or contact is None or iteration - made_at >= refresh:
            current = IterationMatrix.of(plate, jacobian(q), points)
            contact = _Contact(current, chosen if contact is None else contact.chosen)
            made_at = iteration
        shift = _GETRS(current.lu, current.pivots, residual(q))[0]
        if points.size:
            free = current.shapes @ (q - shift)
            free -= surface
            forces = contact.forces(free)
            step = current.response @ forces
            step += shift
        else:
            step = shift
        q = q - step
        change = float(np.abs(step).max())
        if not math.isfinite(change):
            break
        if change <= bound or change <= _TOLERANCE * float(np.abs(q).max()):
            displacement = current.shapes @ q
            if points.size:
                displacement -= current.flexibility @ forces
            return q, forces, displacement, iteration, current
    raise NotConverged(f"Newton did not converge in {MAX_ITERATIONS} iterations")


def _compiled_step(
    chord: Chord,
    plate: ReducedPlate,
    coefficients: StepCoefficients,
    q0: FloatArray,
    v0: FloatArray,
    points: IntArray,
    surface: FloatArray,
    load: FloatArray | None,
    active: NDArray[np.bool_] | None,
    matrix: IterationMatrix,
    acceleration: FloatArray | None,
) -> Solved | tuple[FloatArray, int, bool] | None:
    """``step_reduced`` by the compiled chord iteration on ``matrix`` and the ``active`` set,
    or None where the kernel cannot take the step (the tools' points changed, so the set is
    searched for; the set is singular; a value not finite): the numpy path then takes it
    from its start; or the iterate and iteration the numpy path goes on from, and whether on
    a fresh Jacobian (the kernel's chord ran ``_COMPILED_REFRESH`` iterations) or on
    ``matrix`` (the set changed)."""
    if points.size and active is None:
        return None
    current = matrix.at(plate, points)
    solution: FloatArray | None = _NO_SOLUTION
    case = 0  # no points
    if active is not None and points.size:
        chosen = active.nonzero()[0]
        case = 2 if not chosen.size else 1  # an empty set, or the set's solution
        if chosen.size:
            solution = current.solution(chosen)
            if solution is None:
                return None
    r = plate.size
    extra = np.zeros((2, r))
    if acceleration is not None:
        extra[0] = acceleration
    if load is not None:
        extra[1] = load
    scalars = np.array([coefficients.dt, _TOLERANCE, _COMPILED_REFRESH, _CONTACT_TOLERANCE, case,
                        acceleration is not None, load is not None], dtype=np.float64)  # fmt: skip
    status, q, v, forces, displacement, iterations = chord(
        q0, v0, extra, coefficients.lagging, plate.pairs_matrix, coefficients.pair_diagonal,
        plate.pair_rows, plate.pairs[2], current.lu, current.pivots, current.contact_block,
        solution, surface, scalars,
    )  # fmt: skip
    if status == NOT_FINITE:
        return None
    if status != CONVERGED:
        return q, int(iterations), status == REFRESH_DUE
    return Solved(q, v, forces, displacement, int(iterations), current)


_NO_SOLUTION = np.zeros((0, 0))
_NO_SOLUTION.setflags(write=False)


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
    (usually still right; its block is the matrix's, kept across steps), else
    ``solve_points`` from it."""

    def __init__(self, matrix: IterationMatrix, chosen: IntArray | None) -> None:
        self.matrix = matrix
        self.chosen = chosen  # the active set to try first (None: the violated points)

    def forces(self, violation: FloatArray) -> FloatArray:
        chosen = (violation > 0.0).nonzero()[0] if self.chosen is None else self.chosen
        if chosen.size:
            solution = self.matrix.solution(chosen)
            if solution is not None:
                solved = solution @ violation
                forces, gaps = solved[: violation.size], solved[violation.size :]
                if forces.min() >= 0.0 and _open(gaps, violation):
                    self.chosen = chosen
                    return forces
        elif not (violation > 0.0).any():  # nothing touches: solve_points' zeros at once
            self.chosen = chosen
            return np.zeros(violation.size)
        start = None
        if self.chosen is not None:
            start = np.zeros(violation.size, dtype=bool)
            start[self.chosen] = True
        forces = solve_points(self.matrix.compliance, violation, start)
        self.chosen = (forces > 0.0).nonzero()[0]
        return forces


def _open(gaps: FloatArray, violation: FloatArray) -> bool:
    """Whether the points out of contact stay open: their gaps C F - b at least -tolerance
    (relative to the largest violation, worked out only when a gap is negative)."""
    if not gaps.size:
        return True
    lowest = float(gaps.min())
    return lowest >= 0.0 or lowest >= -_CONTACT_TOLERANCE * float(np.abs(violation).max())


_GETRF, _GETRS, _GETRI = scipy.linalg.lapack.get_lapack_funcs(
    ("getrf", "getrs", "getri"), dtype=np.float64
)
