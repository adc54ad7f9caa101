"""Large deflections of a plate: the von Karman equations solved by Newton with load stepping.

``solve_nonlinear(system, load, inplane="held")`` takes an assembled ``Plate`` system (its
transverse supports, its load vector as ``static``'s loads) and adds the in-plane field the
deflection stretches (``von_karman``): u = (u_x, u_y) on vector P2 triangles sharing the plate
basis's quadrature. In-plane conditions per boundary part:

- "held": u = 0 (the edge cannot move in its plane: the classical clamped plate of the
  large-deflection tables, and the Hencky membrane's limit);
- "sliding": the normal component held, the tangential free (a straight edge along x or y);
- "free": nothing held.

The load is applied in increments, the first ``1 / steps`` of it (None: enough for the linear
deflection's size, ``_steps``), each solved by Newton on the coupled tangent; an increment
whose Newton does not converge is halved, up to ``_MAX_HALVINGS`` times, and one that converges
within ``_QUICK_ITERATIONS`` doubles the next. Units: SI, w and u in m.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.linalg import splu
from skfem import ElementTriP2, ElementVector

from membrane_models.fem.assembly import System
from membrane_models.fem.boundary import resolve_parts
from membrane_models.fem.errors import InvalidLoad, InvalidModel, InvalidSolve, InvalidSupports
from membrane_models.fem.models import Plate
from membrane_models.fem.sampling import derivatives, locate
from membrane_models.fem.static import solve
from membrane_models.fem.von_karman import membrane_stress, residual, tangent

__all__ = [
    "INPLANE",
    "Equilibrium",
    "InPlane",
    "NonlinearSolution",
    "membrane_force",
    "solve_nonlinear",
]

InPlane = Literal["held", "sliding", "free"]
INPLANE: tuple[str, ...] = get_args(InPlane)
FloatArray = NDArray[np.float64]
_MAX_ITERATIONS = 30
_MAX_HALVINGS = 8
# An increment that converged within this many iterations doubles the next: under a large load
# the deflection grows as the load's cube root (a membrane), so later increments come easier.
_QUICK_ITERATIONS = 4
_AXIS_TOL = 1e-9  # a "sliding" edge's facets must lie along x or y within this (radians)


@dataclass(frozen=True, eq=False)
class NonlinearSolution:
    """A converged large-deflection state.

    Attributes:
        w: the deflection's DOF vector on ``system``'s basis (as ``static.solve``'s).
        u: the in-plane displacement's DOF vector on ``inplane_basis`` (m).
        inplane_basis: the vector P2 basis of u.
        increments: the load increments taken; iterations: Newton iterations in all.
        residual: the last relative residual norm.
    """

    w: FloatArray
    u: FloatArray
    inplane_basis: Any
    increments: int
    iterations: int
    residual: float


def solve_nonlinear(
    system: System,
    load: ArrayLike,
    inplane: Mapping[str, str] | str = "held",
    steps: int | None = None,
    tolerance: float = 1e-10,
) -> NonlinearSolution:
    """The von Karman plate's static state under ``load`` (module docstring)."""
    model = system.model
    if not isinstance(model, Plate) or system.element != "argyris":
        raise InvalidModel("large deflections are solved on an Argyris plate (a Plate system)")
    f = np.asarray(load, dtype=np.float64)
    if f.shape != (system.dofs,) or not np.isfinite(f).all():
        raise InvalidLoad(f"a load is a finite vector of {system.dofs} values, not {f.shape}")
    if steps is not None and not (isinstance(steps, int) and steps >= 1):
        raise InvalidSolve(f"steps must be a positive integer or None, not {steps!r}")
    problem = Equilibrium.of(system, inplane, sp.csr_matrix(system.stiffness))
    inplane_basis = problem.inplane_basis
    count = steps or _steps(system, f)
    w, u = np.zeros(system.dofs), np.zeros(inplane_basis.N)
    done, increment, iterations, taken, last = 0.0, 1.0 / count, 0, 0, 0.0
    halvings = 0
    while done < 1.0 - 1e-12:
        target = min(1.0, done + increment)
        attempt = problem.newton(target * f, w, u, tolerance)
        if attempt is None:
            halvings += 1
            if halvings > _MAX_HALVINGS:
                raise InvalidSolve(
                    f"Newton did not converge at {100 * target:.3g} % of the load even in "
                    f"increments of {100 * increment:.3g} %: the load is past what moderate "
                    f"rotations describe, or the in-plane supports let the plate slide away"
                )
            increment /= 2.0
            continue
        w, u, spent, last = attempt
        done, iterations, taken, halvings = target, iterations + spent, taken + 1, 0
        if spent <= _QUICK_ITERATIONS:  # an easy increment: the next may be twice as large
            increment *= 2.0
    return NonlinearSolution(w, u, inplane_basis, taken, iterations, last)


def membrane_force(
    system: System, state: NonlinearSolution, at: ArrayLike
) -> tuple[float, float, float]:
    """(N_x, N_y, N_xy) (N/m) at ``at`` = (x, y): the membrane force the deflection's stretch
    carries there, C(sym(grad u) + 1/2 grad w (x) grad w) (``von_karman``)."""
    plate = system.model
    assert isinstance(plate, Plate)
    xy = np.asarray(at, dtype=np.float64).reshape(1, 2)
    _, slope, _ = derivatives(system, state.w, xy)
    basis = state.inplane_basis
    cells, local = locate(system, xy)
    coefficients = state.u[basis.element_dofs[:, cells]]  # (Nbfun, 1)
    gradient = np.zeros((2, 2))
    for k in range(basis.Nbfun):
        field = basis.elem.gbasis(basis.mapping, local, k, tind=cells)[0]
        gradient += coefficients[k, 0] * np.asarray(field.grad)[:, :, 0, 0]
    strain = 0.5 * (gradient + gradient.T) + 0.5 * np.outer(slope[0], slope[0])
    force = membrane_stress(strain, plate.stretching_stiffness, plate.poisson)
    return float(force[0, 0]), float(force[1, 1]), float(force[0, 1])


def _steps(system: System, load: FloatArray) -> int:
    """Increments for a load: about one per plate thickness of linear deflection, at least 1."""
    linear = solve(system, load)
    assert isinstance(system.model, Plate)
    ratio = float(np.abs(system.vertex_values(linear)).max()) / system.model.thickness
    return max(1, min(200, math.ceil(ratio)))


class Equilibrium:
    """The coupled Newton system on the admissible DOFs: w through the plate's ``transform``,
    u with its held DOFs dropped. ``bending`` is the linear part of the w-block (the plate's
    stiffness; a time step adds its inertia, ``nonlinear_transient``)."""

    def __init__(
        self,
        system: System,
        inplane_basis: Any,
        bending: sp.csr_matrix,
        free_u: Any,
        stretching: float,
        poisson: float,
    ) -> None:
        self.system, self.inplane_basis, self.bending = system, inplane_basis, bending
        self.free_u, self.stretching, self.poisson = free_u, stretching, poisson
        self.pick_u = sp.identity(inplane_basis.N, format="csr")[:, free_u]

    @classmethod
    def of(
        cls, system: System, inplane: Mapping[str, str] | str, linear: sp.csr_matrix
    ) -> Equilibrium:
        """The problem of ``system`` (a plate) with ``inplane`` supports and ``linear`` as the
        w-block's linear part."""
        model = system.model
        assert isinstance(model, Plate)
        inplane_basis = system.basis.with_element(ElementVector(ElementTriP2()))
        held = _inplane_constraints(system, inplane_basis, inplane)
        free_u = np.setdiff1d(np.arange(inplane_basis.N), held)
        return cls(system, inplane_basis, linear, free_u, model.stretching_stiffness, model.poisson)

    def with_linear(self, linear: sp.csr_matrix) -> Equilibrium:
        """The same problem with another linear w-block (a time step's added inertia)."""
        return Equilibrium(self.system, self.inplane_basis, linear, self.free_u,
                           self.stretching, self.poisson)  # fmt: skip

    def newton(
        self, load: FloatArray, w: FloatArray, u: FloatArray, tolerance: float
    ) -> tuple[FloatArray, FloatArray, int, float] | None:
        """The state balancing ``load`` from (w, u), or None when Newton does not converge."""
        system, pick, t_w = self.system, self.pick_u, self.system.transform
        scale = max(float(np.linalg.norm(system.reduce(load))), 1e-300)
        args = (self.system.basis, self.inplane_basis)
        for iteration in range(1, _MAX_ITERATIONS + 1):
            r_w, r_u = residual(*args, self.bending, load, w, u, self.stretching, self.poisson)
            rhs = np.concatenate([system.reduce(r_w), pick.T @ r_u])
            norm = float(np.linalg.norm(rhs)) / scale
            if not math.isfinite(norm):
                return None
            if norm <= tolerance:
                return w, u, iteration - 1, norm
            k = tangent(*args, self.bending, w, u, self.stretching, self.poisson)
            matrix = sp.bmat(
                [
                    [t_w.T @ k.ww @ t_w, t_w.T @ k.uw.T @ pick],
                    [pick.T @ k.uw @ t_w, pick.T @ k.uu @ pick],
                ],
                format="csc",
            )
            try:
                step = splu(matrix).solve(-rhs)
            except RuntimeError:  # a singular tangent: the increment was too large
                return None
            n_w = system.free
            w = w + system.expand(step[:n_w])
            u = u + pick @ step[n_w:]
        return None


def _inplane_constraints(
    system: System, basis: Any, inplane: Mapping[str, str] | str
) -> FloatArray:
    """The in-plane DOFs held (indices into ``basis``), checked against rigid motions."""
    domain = system.domain
    conditions = resolve_parts(domain, inplane, INPLANE, "in-plane condition")
    held: list[Any] = []
    directions: list[int] = []  # 0: u_x held somewhere, 1: u_y held somewhere
    anchored = False
    for part, condition in conditions.items():
        if condition == "free":
            continue
        facets = domain.parts[part]
        dofs = basis.get_dofs(facets=facets)
        if condition == "held":
            held.append(dofs.all())
            anchored = True
            continue
        normal = _straight_normal(domain, facets, part)
        held.append(dofs.all(f"u^{normal + 1}"))
        directions.append(normal)
    if not anchored and len(set(directions)) < 2:
        raise InvalidSupports(
            "the in-plane supports leave the plate free to slide or turn in its plane: hold a "
            "part, or let two non-parallel straight edges slide"
        )
    return np.unique(np.concatenate(held)) if held else np.zeros(0, dtype=np.int64)


def _straight_normal(domain: Any, facets: Any, part: str) -> int:
    """0 when ``part`` runs along y (its normal along x), 1 along x; refused otherwise."""
    mesh = domain.mesh
    ends = mesh.p[:, mesh.facets[:, facets]]
    chord = ends[:, 1] - ends[:, 0]
    angles = np.arctan2(chord[1], chord[0])
    if part in domain.curves or not angles.size:
        raise InvalidSupports(f"{part!r} slides only if it is a straight edge along x or y")
    along_x = np.abs(np.sin(angles)) < _AXIS_TOL
    along_y = np.abs(np.cos(angles)) < _AXIS_TOL
    if along_x.all():
        return 1
    if along_y.all():
        return 0
    raise InvalidSupports(f"{part!r} slides only if it is a straight edge along x or y")
