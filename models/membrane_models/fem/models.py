"""What the tissue is made of: a membrane or a Kirchhoff plate, in SI units.

Both are frozen, validated values (``InvalidModel`` on a bad one). The transverse deflection
``w`` (m) is positive along +z, and so are loads.

- ``Membrane(tension, areal_density)``: tension T (N/m) and mass per area rho_h (kg/m^2);
  ``T grad w . grad v`` and ``rho_h w v``, on quadratic (P2) triangles; wave speed
  c = sqrt(T / rho_h).
- ``Plate(youngs_modulus, poisson, thickness, density, pretension, foundation)``: Kirchhoff
  bending with rigidity D = E h^3 / (12 (1 - nu^2)) (N m), an in-plane pre-tension T (N/m,
  isotropic, ``T grad w . grad v``), a Winkler foundation k (N/m^3, ``k w v``), mass
  ``rho h w v``; on Argyris triangles (C1, quintic).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from membrane_models.fem.errors import InvalidModel

__all__ = ["Membrane", "Model", "Plate"]


@dataclass(frozen=True)
class Membrane:
    """A membrane under isotropic tension.

    Attributes:
        tension: T, N/m (> 0).
        areal_density: rho_h, kg/m^2 (> 0).
    """

    tension: float
    areal_density: float

    def __post_init__(self) -> None:
        _check("tension", self.tension, "N/m", positive=True)
        _check("areal_density", self.areal_density, "kg/m^2", positive=True)

    @property
    def wave_speed(self) -> float:
        """c = sqrt(T / rho_h), m/s."""
        return math.sqrt(self.tension / self.areal_density)


@dataclass(frozen=True)
class Plate:
    """A thin (Kirchhoff) plate, optionally pre-tensioned and on an elastic foundation.

    Attributes:
        youngs_modulus: E, Pa (> 0).
        poisson: nu, in (-1, 0.5].
        thickness: h, m (> 0).
        density: rho, kg/m^3 (> 0).
        pretension: T, N/m (>= 0): an isotropic in-plane tension (its stress T / h).
        foundation: k, N/m^3 (>= 0): a Winkler foundation, pressure k w.
    """

    youngs_modulus: float
    poisson: float
    thickness: float
    density: float
    pretension: float = 0.0
    foundation: float = 0.0

    def __post_init__(self) -> None:
        _check("youngs_modulus", self.youngs_modulus, "Pa", positive=True)
        _check("poisson", self.poisson, "", positive=False)
        if not -1.0 < self.poisson <= 0.5:
            raise InvalidModel(f"poisson must lie in (-1, 0.5], not {self.poisson!r}")
        _check("thickness", self.thickness, "m", positive=True)
        _check("density", self.density, "kg/m^3", positive=True)
        _check("pretension", self.pretension, "N/m", positive=False, negative=False)
        _check("foundation", self.foundation, "N/m^3", positive=False, negative=False)

    @property
    def rigidity(self) -> float:
        """D = E h^3 / (12 (1 - nu^2)), N m."""
        return self.youngs_modulus * self.thickness**3 / (12.0 * (1.0 - self.poisson**2))

    @property
    def stretching_stiffness(self) -> float:
        """A = E h / (1 - nu^2), N/m: the in-plane (plane stress) stiffness of a large
        deflection's stretch (``fem.von_karman``)."""
        return self.youngs_modulus * self.thickness / (1.0 - self.poisson**2)

    @property
    def areal_density(self) -> float:
        """rho h, kg/m^2."""
        return self.density * self.thickness


Model = Membrane | Plate


def _check(name: str, value: float, unit: str, positive: bool, negative: bool = True) -> None:
    real = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not (real and math.isfinite(value)):
        raise InvalidModel(
            f"{name} must be a finite number{f' ({unit})' if unit else ''}, not {value!r}"
        )
    if positive and not value > 0:
        raise InvalidModel(f"{name} must be positive, not {value!r} {unit}".rstrip())
    if not negative and value < 0:
        raise InvalidModel(f"{name} must not be negative, not {value!r} {unit}".rstrip())
