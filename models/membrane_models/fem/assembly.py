"""A model on a domain with its supports, assembled once: the stiffness, the mass, the
constrained space.

``assemble(domain, model, supports)`` picks the element (a membrane: P2, isoparametric on the
curved parts, whose edge midpoints sit on the exact curve, or P1 for ``contact``'s presses; a
plate: Argyris, or Morley for convergence studies only; ``elements``: scikit-fem's, evaluated
in local coordinates), assembles the weak forms of ``forms`` and the constrained space of
``boundary`` (refusing rigid-body modes there, before any solve), and returns a ``System``.

Units: SI throughout. A DOF vector ``u`` holds the element's DOFs (w in m; Argyris's slopes
and curvatures in m/m and 1/m), the stiffness K maps it to generalised forces (N, N m, ...),
the mass M is the kinetic energy's matrix (kg, ...). Every admissible vector is
``u = T r``; the solves work on ``K_r = T' K T`` and ``M_r = T' M T``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from skfem import Basis, ElementTriP1, ElementTriP2, MeshTri2

from membrane_models.fem import forms
from membrane_models.fem.boundary import Condition, constrain, resolve_supports
from membrane_models.fem.elements import LocalArgyris, LocalMorley
from membrane_models.fem.errors import InvalidModel
from membrane_models.fem.geometry import Domain
from membrane_models.fem.models import Membrane, Model, Plate

__all__ = ["ELEMENTS", "ElementName", "System", "assemble"]

ElementName = Literal["argyris", "morley", "p1", "p2"]
ELEMENTS: dict[str, tuple[type, int]] = {  # element class, quadrature order
    "argyris": (LocalArgyris, 10),
    "morley": (LocalMorley, 4),
    "p1": (ElementTriP1, 2),
    "p2": (ElementTriP2, 6),
}
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class System:
    """An assembled model (module docstring).

    Attributes:
        domain, model, element, supports, exact_frame: what was assembled.
        basis: the scikit-fem basis (its element, its DOF numbering).
        stiffness, mass: K and M, ``(N, N)``.
        transform: T, ``(N, n)``.
        reduced_stiffness, reduced_mass: ``T' K T`` and ``T' M T``, ``(n, n)``.
    """

    domain: Domain
    model: Model
    element: ElementName
    supports: Mapping[str, Condition]
    exact_frame: bool
    basis: Any
    stiffness: sp.csr_matrix
    mass: sp.csr_matrix
    transform: sp.csr_matrix
    reduced_stiffness: sp.csc_matrix
    reduced_mass: sp.csc_matrix

    @property
    def dofs(self) -> int:
        """N, the element's DOFs."""
        return int(self.transform.shape[0])

    @property
    def free(self) -> int:
        """n, the DOFs the supports leave free."""
        return int(self.transform.shape[1])

    def reduce(self, load: FloatArray) -> FloatArray:
        """``T' f``: a load vector ``(N,)`` or ``(N, k)`` on the constrained space."""
        return np.asarray(self.transform.T @ load, dtype=np.float64)

    def expand(self, reduced: FloatArray) -> FloatArray:
        """``T r``: a constrained vector back on every DOF."""
        return np.asarray(self.transform @ reduced, dtype=np.float64)

    def vertex_values(self, u: FloatArray) -> FloatArray:
        """w at the mesh's vertices (m), for any element (Morley's only continuous values)."""
        return np.asarray(np.asarray(u)[self.basis.nodal_dofs[0]], dtype=np.float64)


def assemble(
    domain: Domain,
    model: Model,
    supports: Mapping[str, str] | str,
    element: ElementName | None = None,
    exact_frame: bool = True,
) -> System:
    """K, M and the constrained space of ``model`` on ``domain`` (module docstring).

    Args:
        supports: part -> "clamped" / "simply_supported" / "free" (unnamed parts are free), or
            one condition for every part. A membrane carries no moment: clamped and simply
            supported both fix w.
        element: "argyris" (a plate's default) or "morley" for a plate, "p2" (default) or
            "p1" (straight triangles, for ``contact.press``) for a membrane.
        exact_frame: a curved part's conditions in its exact frame (``boundary``).
    """
    conditions = resolve_supports(domain, supports)
    if isinstance(model, Membrane):
        kind = element or "p2"
        if kind == "p2":
            basis = Basis(_curved_mesh(domain), ElementTriP2(), intorder=ELEMENTS["p2"][1])
        elif kind == "p1":  # straight triangles: the contact reference's (``contact``)
            basis = Basis(domain.mesh, ElementTriP1(), intorder=ELEMENTS["p1"][1])
        else:
            raise InvalidModel(f"a membrane is assembled on p2 (or p1) triangles, not {kind!r}")
        motions, what = 1, "membrane"
    elif isinstance(model, Plate):
        kind = element or "argyris"
        if kind not in ("argyris", "morley"):
            raise InvalidModel(f"a plate is assembled on argyris or morley triangles, not {kind!r}")
        element_class, order = ELEMENTS[kind]
        # a fresh element per basis: it caches its mesh's inverse Vandermonde matrices
        basis = Basis(domain.mesh, element_class(), intorder=order)
        motions = 0 if model.foundation > 0 else 1 if model.pretension > 0 else 3
        what = "plate"
    else:
        raise InvalidModel(f"a model is a Membrane or a Plate, not {type(model).__name__}")
    # the rigid-body check, before any form is assembled
    transform = constrain(domain, basis, kind, conditions, exact_frame, motions, what).transform
    stiffness = sp.csr_matrix(_stiffness(basis, model))
    mass = sp.csr_matrix(forms.weighted_mass.assemble(basis, coefficient=model.areal_density))
    reduced_k = sp.csc_matrix(transform.T @ stiffness @ transform)
    reduced_m = sp.csc_matrix(transform.T @ mass @ transform)
    return System(
        domain,
        model,
        kind,
        dict(conditions),
        exact_frame,
        basis,
        stiffness,
        mass,
        transform,
        reduced_k,
        reduced_m,
    )


def _stiffness(basis: Any, model: Model) -> Any:
    """The model's stiffness: its forms of ``forms``, summed."""
    if isinstance(model, Membrane):
        return forms.tension.assemble(basis, tension=model.tension)
    stiffness = forms.bending.assemble(basis, rigidity=model.rigidity, poisson=model.poisson)
    if model.pretension > 0:
        stiffness = stiffness + forms.tension.assemble(basis, tension=model.pretension)
    if model.foundation > 0:
        stiffness = stiffness + forms.weighted_mass.assemble(basis, coefficient=model.foundation)
    return stiffness


def _curved_mesh(domain: Domain) -> Any:
    """The domain's mesh as a quadratic one, the curved parts' edge midpoints on their curves."""
    mesh = MeshTri2.from_mesh(domain.mesh)
    if not domain.curves:
        return mesh
    doflocs = mesh.doflocs.copy()
    for part, curve in domain.curves.items():
        nodes = mesh.dofs.get_facet_dofs(domain.parts[part]).flatten()
        doflocs[:, nodes] = curve.project(doflocs[:, nodes])
    return MeshTri2(doflocs, mesh.t)
