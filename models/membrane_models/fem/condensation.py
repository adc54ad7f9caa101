"""The in-plane field of a von Karman plate condensed onto pairs of transverse shapes.

For transverse shapes v_j, v_k (slopes g = grad v) the quadratic membrane strain
e_jk = (g_j (x) g_k + g_k (x) g_j) / 4 drives the in-plane displacement U_jk,

    K_uu U_jk = -b_jk,   b_jk(v) = int C(e_jk) : sym grad v,

over the admissible in-plane fields (the edges' in-plane condition), and the condensed strain
is E_jk = sym grad U_jk + e_jk. The stretching energy's quartic coefficients are the products
G_jklm = int C(E_jk) : E_lm, C the plane-stress stiffness times the thickness (N/m).

Since U_lm balances its own strain (int C(E_lm) : sym grad v = 0 for every admissible v),
int C(E_jk) : sym grad U_lm = 0 and G_jklm = int C(E_jk) : e_lm: a new pair's row of G needs
its own in-plane solve and only the quadratic strains of the others (``reduced_plate`` builds
G whole, ``adapted_basis`` adds the rows of a new shape).

Units: SI; strains per unit coordinate squared, G in N / (kg^2 m^2) for mass-normalised shapes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import SuperLU, splu
from skfem.helpers import grad, sym_grad

from membrane_models.fem.assembly import System
from membrane_models.fem.models import Plate
from membrane_models.fem.nonlinear import Equilibrium
from membrane_models.fem.von_karman import tangent

__all__ = ["Condensation"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Condensation:
    """The condensed in-plane problem of a plate (module docstring).

    Attributes:
        stretching, poisson: E h / (1 - nu^2) (N/m) and nu.
        plate_basis, inplane_basis: scikit-fem's bases of w and of u (shared quadrature).
        pick: the admissible in-plane DOFs (N_u, free), solver: K_uu's LU on them.
        strains: sym grad of every in-plane local basis function (J, 2, 2, E, Q).
        dx: the quadrature weights (E, Q), m^2.
    """

    stretching: float
    poisson: float
    plate_basis: Any
    inplane_basis: Any
    pick: sp.csr_matrix
    solver: SuperLU
    strains: FloatArray
    dx: FloatArray

    @classmethod
    def of(cls, system: System, inplane: Mapping[str, str] | str) -> Condensation:
        """The condensation of ``system`` (an Argyris ``Plate``) under ``inplane`` supports."""
        plate = system.model
        assert isinstance(plate, Plate)
        a, nu = plate.stretching_stiffness, plate.poisson
        problem = Equilibrium.of(system, inplane, sp.csr_matrix(system.stiffness))
        inplane_basis, pick = problem.inplane_basis, problem.pick_u
        zeros_w, zeros_u = np.zeros(system.dofs), np.zeros(inplane_basis.N)
        k_uu = tangent(system.basis, inplane_basis, system.stiffness, zeros_w, zeros_u, a, nu).uu
        solver = splu(sp.csc_matrix(pick.T @ k_uu @ pick))
        strains = np.stack([np.asarray(sym_grad(psi[0])) for psi in inplane_basis.basis])
        return cls(a, nu, system.basis, inplane_basis, pick, solver, strains,
                   np.asarray(system.basis.dx))  # fmt: skip

    def slopes(self, vectors: FloatArray) -> FloatArray:
        """grad v of each column of ``vectors`` (DOFs, n) at the quadrature points (n, 2, E, Q)."""
        return np.stack([np.asarray(grad(self.plate_basis.interpolate(v))) for v in vectors.T])

    def quadratic(self, left: FloatArray, right: FloatArray) -> FloatArray:
        """e of the pairs of slopes ``left[p]``, ``right[p]`` (P, 2, 2, E, Q)."""
        return 0.25 * (
            np.einsum("paeq,pbeq->pabeq", left, right) + np.einsum("paeq,pbeq->pabeq", right, left)
        )

    def condensed(self, e: FloatArray) -> FloatArray:
        """E = e + sym grad U of the pairs' quadratic strains ``e`` (P, 2, 2, E, Q)."""
        a, nu, dofs = self.stretching, self.poisson, self.inplane_basis.element_dofs
        traces = np.einsum("paaeq->peq", e)[:, None, None]
        stress = a * ((1 - nu) * e + nu * traces * np.eye(2)[None, :, :, None, None])
        local = np.einsum("pabeq,jabeq,eq->pje", stress, self.strains, self.dx, optimize=True)
        loads = np.zeros((e.shape[0], self.inplane_basis.N))
        for index in range(e.shape[0]):
            np.add.at(loads[index], dofs, local[index])
        solved = self.pick @ self.solver.solve(np.ascontiguousarray(-(self.pick.T @ loads.T)))
        coefficients = solved[dofs]  # (J, E, P)
        shift = np.einsum("jep,jabeq->pabeq", coefficients, self.strains, optimize=True)
        return np.asarray(e + shift)

    def against_slopes(self, strain: FloatArray, slopes: FloatArray) -> FloatArray:
        """int C(A_p) : e_lm (P, n, n) of strains ``strain`` (P, 2, 2, E, Q) against the
        quadratic strains of every pair of ``slopes`` (n, 2, E, Q): 1/2 int g_l . C(A_p) g_m,
        a product of (n, E Q) matrices per strain rather than a quadratic strain per pair."""
        a, nu = self.stretching, self.poisson
        n = slopes.shape[0]
        gx, gy = slopes[:, 0].reshape(n, -1), slopes[:, 1].reshape(n, -1)
        weight = 0.5 * a * self.dx.ravel()
        products = np.empty((strain.shape[0], n, n))
        for p, tensor in enumerate(strain):
            xx, yy, xy = (tensor[i, j].ravel() for i, j in ((0, 0), (1, 1), (0, 1)))
            sxx, syy, sxy = weight * (xx + nu * yy), weight * (yy + nu * xx), weight * (1 - nu) * xy
            cross = (gx * sxy) @ gy.T
            products[p] = (gx * sxx) @ gx.T + (gy * syy) @ gy.T + cross + cross.T
        return products

    def components(self, strain: FloatArray) -> FloatArray:
        """xx, yy, xy of ``strain`` (P, 2, 2, E, Q) times sqrt(dx), flattened: (P, 3, E Q), so
        that ``products`` is a sum over the quadrature."""
        root = np.sqrt(self.dx)
        parts = [strain[:, 0, 0] * root, strain[:, 1, 1] * root, strain[:, 0, 1] * root]
        return np.stack(parts, axis=1).reshape(strain.shape[0], 3, -1)

    def products(self, left: FloatArray, right: FloatArray) -> FloatArray:
        """int C(A_p) : B_s (P, S) of strains given by their ``components``."""
        a, nu = self.stretching, self.poisson
        xx, yy, xy = left[:, 0], left[:, 1], left[:, 2]
        xx2, yy2, xy2 = right[:, 0], right[:, 1], right[:, 2]
        trace, trace2 = xx + yy, xx2 + yy2
        return np.asarray(
            a * ((1 - nu) * (xx @ xx2.T + yy @ yy2.T + 2.0 * xy @ xy2.T) + nu * trace @ trace2.T)
        )
