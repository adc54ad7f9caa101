"""The von Karman plate's weak forms: bending coupled to the membrane stretching it causes.

A plate deflected by w (m, along +z) with in-plane displacements u = (u_x, u_y) (m) stretches
its mid-surface by the Green-Lagrange strain of moderate rotations,

    eps = sym(grad u) + 1/2 grad w (x) grad w,

carrying the membrane force N = A [(1 - nu) eps + nu tr(eps) I] (N/m, A = E h / (1 - nu^2)).
The energy is the bending energy (``forms.bending``) plus 1/2 N : eps, less the load's work.
Its first variation is the residual, its second the tangent, both assembled here for a given
state (w on the plate's basis, u on a vector P2 basis sharing its quadrature):

- R_u(v) = N : sym(grad v),
- R_w(v) = (bending of w)(v) + (N grad w) . grad v - f(v),
- K_uu = C(sym grad du) : sym grad v,  K_uw = C(sym(grad w (x) grad dw)) : sym grad v,
- K_ww = bending + (N grad dw) . grad v + C(sym(grad w (x) grad dw)) : sym(grad w (x) grad v),

with C(e) = A [(1 - nu) e + nu tr(e) I] (``membrane_stress``) and K_wu the transpose of K_uw.
Linearised at w = 0 this is the Kirchhoff plate and a decoupled plane stress problem: the
small-load limit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from skfem import BilinearForm, Functional, LinearForm
from skfem.helpers import ddot, dot, eye, grad, sym_grad, trace

__all__ = ["Tangent", "energy", "membrane_strain", "membrane_stress", "residual", "tangent"]


def _outer(a: Any, b: Any) -> Any:
    return np.einsum("i...,j...->ij...", a, b)


def membrane_stress(e: Any, stretching: float, poisson: float) -> Any:
    """C(e) = A [(1 - nu) e + nu tr(e) I]: the membrane force (N/m) of a strain e, A the
    plate's ``stretching_stiffness``."""
    return stretching * ((1.0 - poisson) * e + poisson * eye(trace(e), 2))


def membrane_strain(w: Any) -> Any:
    """eps at the quadrature points of the state fields ``w.u`` and ``w.w`` (or a mapping of
    them)."""
    u, deflection = (w["u"], w["w"]) if isinstance(w, dict) else (w.u, w.w)
    slope = grad(deflection)
    return sym_grad(u) + 0.5 * _outer(slope, slope)


# The state's fields (``w.slope``: grad w, ``w.force``: N, at the quadrature points) are
# computed once per assembly (``_state``), not once per pair of basis functions.


@LinearForm
def _inplane_residual(v: Any, w: Any) -> Any:
    return ddot(w.force, sym_grad(v))


@LinearForm
def _coupling_residual(v: Any, w: Any) -> Any:
    return dot(np.einsum("ij...,j...->i...", w.force, w.slope), grad(v))


@BilinearForm
def _inplane_tangent(du: Any, v: Any, w: Any) -> Any:
    return ddot(membrane_stress(sym_grad(du), w.stretching, w.poisson), sym_grad(v))


@Functional
def _stretching_energy(w: Any) -> Any:
    strain = membrane_strain(w)
    return 0.5 * ddot(membrane_stress(strain, w.stretching, w.poisson), strain)


def energy(
    plate_basis: Any,
    inplane_basis: Any,
    bending: sp.spmatrix,
    load: Any,
    w_dofs: Any,
    u_dofs: Any,
    stretching: float,
    poisson: float,
) -> float:
    """The total potential energy (J): bending, stretching, less the load's work."""
    fields = _fields(plate_basis, inplane_basis, w_dofs, u_dofs)
    stretch = _stretching_energy.assemble(
        plate_basis, stretching=stretching, poisson=poisson, **fields
    )
    return float(0.5 * w_dofs @ (bending @ w_dofs) + stretch - load @ w_dofs)


def _fields(plate_basis: Any, inplane_basis: Any, w_dofs: Any, u_dofs: Any) -> dict[str, Any]:
    return {"w": plate_basis.interpolate(w_dofs), "u": inplane_basis.interpolate(u_dofs)}


def _state(
    plate_basis: Any,
    inplane_basis: Any,
    w_dofs: Any,
    u_dofs: Any,
    stretching: float,
    poisson: float,
) -> dict[str, Any]:
    """The forms' keywords at a state: the coefficients, grad w and N at the quadrature points."""
    fields = _fields(plate_basis, inplane_basis, w_dofs, u_dofs)
    slope = np.asarray(grad(fields["w"]))
    force = membrane_stress(membrane_strain(fields), stretching, poisson)
    return {"stretching": stretching, "poisson": poisson, "slope": slope, "force": force}


def residual(
    plate_basis: Any,
    inplane_basis: Any,
    bending: sp.spmatrix,
    load: Any,
    w_dofs: Any,
    u_dofs: Any,
    stretching: float,
    poisson: float,
) -> tuple[Any, Any]:
    """(R_w, R_u): the energy's gradient on the plate's and the in-plane DOFs (N, N m, ...)."""
    state = _state(plate_basis, inplane_basis, w_dofs, u_dofs, stretching, poisson)
    r_w = bending @ w_dofs + _coupling_residual.assemble(plate_basis, **state) - load
    r_u = _inplane_residual.assemble(inplane_basis, **state)
    return np.asarray(r_w), np.asarray(r_u)


class Tangent:
    """The energy's Hessian at a state, by blocks: ``ww`` (with the bending), ``uw`` (rows: u,
    columns: w), ``uu``; ``wu`` is ``uw``'s transpose."""

    def __init__(self, ww: sp.spmatrix, uw: sp.spmatrix, uu: sp.spmatrix) -> None:
        self.ww, self.uw, self.uu = ww, uw, uu


def tangent(
    plate_basis: Any,
    inplane_basis: Any,
    bending: sp.spmatrix,
    w_dofs: Any,
    u_dofs: Any,
    stretching: float,
    poisson: float,
) -> Tangent:
    """The Hessian at a state (module docstring). The state's blocks are contracted over every
    element at once from the bases' cached gradients, with C(sym(s (x) g_l)) : sym(s (x) g_k)
    = A [(1 - nu) / 2 |s|^2 g_k . g_l + (1 + nu) / 2 (s . g_k)(s . g_l)]: scikit-fem's form
    kernel, called once per pair of the 21 Argyris functions, cost 0.2 s per tangent even on
    200 DOFs. ``tests/models/fem`` checks it against the residual's differences."""
    state = _state(plate_basis, inplane_basis, w_dofs, u_dofs, stretching, poisson)
    slope, force = state["slope"], state["force"]  # (2, E, Q), (2, 2, E, Q)
    dx = plate_basis.dx  # (E, Q)
    g = np.stack([np.asarray(phi[0].grad) for phi in plate_basis.basis])  # (K, 2, E, Q)
    strain = np.stack([np.asarray(sym_grad(psi[0])) for psi in inplane_basis.basis])  # (J,2,2,E,Q)
    p = np.einsum("ieq,kieq->keq", slope, g)  # s . grad phi_k
    squared = np.einsum("ieq,ieq->eq", slope, slope)
    a, nu = stretching, poisson
    geometric = np.einsum("kieq,ijeq,ljeq,eq->ekl", g, force, g, dx)
    material = np.einsum("kieq,lieq,eq->ekl", g, g, dx * a * (1 - nu) / 2 * squared)
    material += np.einsum("keq,leq,eq->ekl", p, p, dx * a * (1 + nu) / 2)
    ww = bending + _scatter(geometric + material, plate_basis, plate_basis)
    # C(sym(s (x) grad phi_l)) : eps_j = A [(1 - nu) s' eps_j grad phi_l + nu p_l tr eps_j]
    traces = strain[:, 0, 0] + strain[:, 1, 1]
    cross = (1 - nu) * np.einsum("ieq,jikeq,lkeq,eq->ejl", slope, strain, g, dx * a)
    cross += nu * np.einsum("leq,jeq,eq->ejl", p, traces, dx * a)
    uw = _scatter(cross, inplane_basis, plate_basis)
    uu = _inplane_tangent.assemble(inplane_basis, **state)
    return Tangent(sp.csr_matrix(ww), uw, sp.csr_matrix(uu))


def _scatter(local: Any, rows: Any, columns: Any) -> sp.csr_matrix:
    """Element matrices ``(E, I, J)`` into the global ``(rows.N, columns.N)`` matrix."""
    r = rows.element_dofs.T[:, :, None]  # (E, I, 1)
    c = columns.element_dofs.T[:, None, :]  # (E, 1, J)
    r, c = np.broadcast_to(r, local.shape), np.broadcast_to(c, local.shape)
    shape = (rows.N, columns.N)
    return sp.coo_matrix((local.ravel(), (r.ravel(), c.ravel())), shape=shape).tocsr()
