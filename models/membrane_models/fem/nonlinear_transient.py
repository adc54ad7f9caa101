"""The von Karman plate in time: Newmark's average acceleration with Newton at every step.

The reference for large-deflection dynamics (the reduced live engines are checked against it):
the transverse inertia M w'' of the plate (``System.mass``), the in-plane field quasi-static
(its inertia is smaller by (h / L)^2 and its waves far faster than the bending ones), no
damping. Each step of dt solves, on the admissible DOFs,

    (4 / dt^2) M (w - w*) + R(w, u) = f(t + dt),   R_u(w, u) = 0,
    w* = w_n + dt v_n + dt^2 / 4 a_n,

by Newton on the coupled tangent with (4 / dt^2) M added to its w-block (``nonlinear``'s
``Equilibrium``), then a = (4 / dt^2) (w - w*), v = v_n + dt (a_n + a) / 2. The scheme is
unconditionally stable and conserves energy exactly on a linear plate; on this quartic energy
only approximately, which ``energy`` measures.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from membrane_models.fem.assembly import System
from membrane_models.fem.errors import InvalidLoad, InvalidModel, InvalidSolve
from membrane_models.fem.models import Plate
from membrane_models.fem.nonlinear import Equilibrium
from membrane_models.fem.von_karman import energy, residual

__all__ = ["NonlinearHistory", "step_nonlinear"]

FloatArray = NDArray[np.float64]
MAX_VALUES = 50_000_000  # steps x DOFs kept: 400 MB of float64


@dataclass(frozen=True, eq=False)
class NonlinearHistory:
    """A run: times ``(s + 1,)``, w ``(s + 1, N)`` and u ``(s + 1, N_u)`` DOF vectors, and the
    total energy (kinetic, bending and stretching, less the load's work at each time's load) at
    each time (J)."""

    times: FloatArray
    w: FloatArray
    u: FloatArray
    energy: FloatArray
    iterations: int


def step_nonlinear(
    system: System,
    load: Callable[[float], FloatArray] | FloatArray,
    dt: float,
    steps: int,
    inplane: Mapping[str, str] | str = "held",
    velocity: FloatArray | None = None,
    tolerance: float = 1e-10,
) -> NonlinearHistory:
    """``steps`` steps of ``dt`` (s) from w = 0, at rest or with the initial ``velocity`` (an
    admissible DOF vector, m/s: a mode shape, say), under ``load`` (a DOF vector, or a
    function of time giving one)."""
    if not isinstance(system.model, Plate) or system.element != "argyris":
        raise InvalidModel("large deflections are solved on an Argyris plate (a Plate system)")
    if not (np.isfinite(dt) and dt > 0) or not (isinstance(steps, int) and steps >= 1):
        raise InvalidSolve(f"dt must be > 0 and steps a positive integer, not {dt!r}, {steps!r}")
    force = _load_function(system, load)
    inertia = 4.0 / dt**2
    mass = sp.csr_matrix(system.mass)
    plain = Equilibrium.of(system, inplane, sp.csr_matrix(system.stiffness))
    problem = plain.with_linear(sp.csr_matrix(system.stiffness + inertia * mass))
    if steps * (system.dofs + problem.inplane_basis.N) > MAX_VALUES:
        raise InvalidSolve(f"{steps} steps of {system.dofs} DOFs: more than {MAX_VALUES} values")
    w, u = np.zeros(system.dofs), np.zeros(problem.inplane_basis.N)
    v = np.zeros(system.dofs) if velocity is None else np.asarray(velocity, dtype=np.float64)
    if v.shape != (system.dofs,) or not np.isfinite(v).all():
        raise InvalidLoad(f"a velocity is a finite vector of {system.dofs} values, not {v.shape}")
    a = _acceleration(system, plain, force(0.0), w, u)
    history_w, history_u, energies = [w], [u], [_energy(system, plain, mass, force(0.0), w, u, v)]
    iterations = 0
    for n in range(1, steps + 1):
        predicted = w + dt * v + dt**2 / 4 * a
        f = force(n * dt)
        solved = problem.newton(f + inertia * (mass @ predicted), w, u, tolerance)
        if solved is None:
            raise InvalidSolve(f"Newton did not converge at step {n} (t = {n * dt:g} s)")
        w, u, spent, _ = solved
        iterations += spent
        accelerated = inertia * (w - predicted)
        v, a = v + dt / 2 * (a + accelerated), accelerated
        history_w.append(w)
        history_u.append(u)
        energies.append(_energy(system, plain, mass, f, w, u, v))
    times = np.asarray(dt * np.arange(steps + 1), dtype=np.float64)
    return NonlinearHistory(times, np.array(history_w), np.array(history_u),
                            np.array(energies), iterations)  # fmt: skip


def _load_function(
    system: System, load: Callable[[float], FloatArray] | FloatArray
) -> Callable[[float], FloatArray]:
    if callable(load):
        return load
    f = np.asarray(load, dtype=np.float64)
    if f.shape != (system.dofs,) or not np.isfinite(f).all():
        raise InvalidLoad(f"a load is a finite vector of {system.dofs} values, not {f.shape}")
    return lambda t: f


def _acceleration(
    system: System, plain: Equilibrium, f: FloatArray, w: FloatArray, u: FloatArray
) -> FloatArray:
    """M a = f - R(w) on the admissible space (the in-plane field at rest with w)."""
    r_w, _ = residual(system.basis, plain.inplane_basis, plain.bending, f, w, u,
                      plain.stretching, plain.poisson)  # fmt: skip
    reduced = splu(system.reduced_mass).solve(system.reduce(-r_w))
    return system.expand(reduced)


def _energy(
    system: System,
    plain: Equilibrium,
    mass: sp.csr_matrix,
    f: FloatArray,
    w: FloatArray,
    u: FloatArray,
    v: FloatArray,
) -> float:
    potential = energy(system.basis, plain.inplane_basis, plain.bending, f, w, u,
                       plain.stretching, plain.poisson)  # fmt: skip
    return float(0.5 * v @ (mass @ v) + potential)
