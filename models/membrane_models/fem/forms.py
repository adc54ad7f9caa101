"""The physics as weak forms, one term each (scikit-fem's own layout, as ``skfem.models``).

Each form takes its coefficient as a keyword of ``assemble`` (a number, SI units), so that a
model's parameters never live in a form:

- ``bending``: D [(1 - nu) d2u : d2v + nu lap(u) lap(v)], the Kirchhoff plate's bending
  energy (``rigidity`` D in N m, ``poisson`` nu); needs a C1 (Argyris) or a nonconforming
  (Morley) element's second derivatives;
- ``tension``: T grad u . grad v (``tension`` T in N/m): a membrane, or a plate's in-plane
  pre-tension;
- ``weighted_mass``: c u v (``coefficient`` c): the mass (rho_h, kg/m^2) or a Winkler
  foundation (k, N/m^3);
- ``pressure``: q v (``pressure`` q in Pa, positive along +z).
"""

from __future__ import annotations

from typing import Any

from skfem import BilinearForm, LinearForm
from skfem.helpers import dd, ddot, dot, grad, trace

__all__ = ["bending", "pressure", "tension", "weighted_mass"]


@BilinearForm
def bending(u: Any, v: Any, w: Any) -> Any:
    hu, hv = dd(u), dd(v)
    return w.rigidity * ((1.0 - w.poisson) * ddot(hu, hv) + w.poisson * trace(hu) * trace(hv))


@BilinearForm
def tension(u: Any, v: Any, w: Any) -> Any:
    return w.tension * dot(grad(u), grad(v))


@BilinearForm
def weighted_mass(u: Any, v: Any, w: Any) -> Any:
    return w.coefficient * u * v


@LinearForm
def pressure(v: Any, w: Any) -> Any:
    return w.pressure * v
