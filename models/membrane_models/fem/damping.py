"""How fast the modes lose energy: a setting the live modal basis will use.

``Damping`` gives each mode's damping ratio zeta_k (dimensionless) from its angular frequency
omega_k (rad/s), in one of two forms:

- modal: one ratio for every mode, ``Damping.modal(zeta)``;
- Rayleigh: C = alpha M + beta K, so zeta_k = alpha / (2 omega_k) + beta omega_k / 2,
  ``Damping.rayleigh(alpha, beta)`` (alpha in 1/s, beta in s).

A mode with zeta_k < 1 is underdamped; nothing here refuses an overdamped one.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.fem.errors import InvalidModel

__all__ = ["Damping"]


@dataclass(frozen=True)
class Damping:
    """Modal (``zeta``) or Rayleigh (``alpha``, ``beta``) damping; not both.

    Attributes:
        zeta: the ratio of every mode (>= 0).
        alpha: mass-proportional coefficient, 1/s (>= 0).
        beta: stiffness-proportional coefficient, s (>= 0).
    """

    zeta: float = 0.0
    alpha: float = 0.0
    beta: float = 0.0

    def __post_init__(self) -> None:
        for name in ("zeta", "alpha", "beta"):
            value = getattr(self, name)
            real = isinstance(value, numbers.Real) and not isinstance(value, bool)
            if not (real and math.isfinite(value) and value >= 0):
                raise InvalidModel(f"damping {name} must be a finite number >= 0, not {value!r}")
        if self.zeta > 0 and (self.alpha > 0 or self.beta > 0):
            raise InvalidModel("damping is modal (zeta) or Rayleigh (alpha, beta), not both")

    @classmethod
    def modal(cls, zeta: float) -> Damping:
        return cls(zeta=zeta)

    @classmethod
    def rayleigh(cls, alpha: float, beta: float) -> Damping:
        return cls(alpha=alpha, beta=beta)

    @property
    def is_rayleigh(self) -> bool:
        return self.alpha > 0 or self.beta > 0

    def ratios(self, omega: ArrayLike) -> NDArray[np.float64]:
        """zeta_k for angular frequencies omega_k > 0 (rad/s)."""
        w = np.asarray(omega, dtype=np.float64)
        if not (np.isfinite(w).all() and (w > 0).all()):
            raise InvalidModel("damping ratios need finite angular frequencies > 0")
        if not self.is_rayleigh:
            return np.full(w.shape, self.zeta)
        return np.asarray(self.alpha / (2.0 * w) + self.beta * w / 2.0, dtype=np.float64)
