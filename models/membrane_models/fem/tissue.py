"""A physical tissue as a live scene serves it: shape, material, supports, damping, modes, tools.

``Tissue`` is what a scene's ``[tissue]`` table becomes (the server validates the table and
builds one): everything the FEM live engine needs (``live_engine``) and what ``describe`` says
of the tissue, in SI units. It plays the part a dimensionless ``Problem`` plays for the sine
engine.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from membrane_models.fem.assembly import ElementName
from membrane_models.fem.damping import Damping
from membrane_models.fem.geometry import Domain
from membrane_models.fem.models import Membrane, Model, Plate

__all__ = ["Tissue"]


@dataclass(frozen=True, eq=False)
class Tissue:
    """A FEM tissue for the live engine.

    Attributes:
        name: what the tissue is, in words (``describe``'s model name).
        domain: the meshed shape (m).
        model: a ``Plate`` or a ``Membrane``.
        supports: one condition for every boundary part, or part -> condition.
        damping: modal or Rayleigh (``Damping``).
        modes: how many of the lowest modes the engine steps (the static correction carries
            the rest).
        radii: the footprint radii sessions may use (m; 0: point forces, plates only).
        element: the element (default: Argyris for a plate, P2 for a membrane).
        shape: the shape's description for ``describe`` (kind and sizes in m).
    """

    spatial_dims: ClassVar[int] = 2

    name: str
    domain: Domain
    model: Model
    supports: Mapping[str, str] | str
    damping: Damping
    modes: int
    radii: tuple[float, ...]
    element: ElementName | None = None
    shape: Mapping[str, Any] = field(default_factory=dict)

    @property
    def lower(self) -> tuple[float, float]:
        """The bounding box's lower corner (m)."""
        points = self.domain.mesh.p
        return float(points[0].min()), float(points[1].min())

    @property
    def upper(self) -> tuple[float, float]:
        """The bounding box's upper corner (m)."""
        points = self.domain.mesh.p
        return float(points[0].max()), float(points[1].max())

    def describe(self) -> dict[str, Any]:
        """The tissue in ``describe``'s ``model`` field: SI numbers, named."""
        described: dict[str, Any] = {
            "name": self.name,
            "kind": "plate" if isinstance(self.model, Plate) else "membrane",
            "units": "SI",
            "shape": dict(self.shape),
            "supports": self.supports if isinstance(self.supports, str) else dict(self.supports),
            "mesh": {
                "triangles": int(self.domain.mesh.t.shape[1]),
                "element_size_m": float(self.domain.size),
                "element": self.element or ("argyris" if isinstance(self.model, Plate) else "p2"),
            },
            "modes": self.modes,
            "radii_m": list(self.radii),
            "damping": _damping(self.damping),
        }
        if isinstance(self.model, Plate):
            described["material"] = {
                "youngs_modulus_pa": self.model.youngs_modulus,
                "poisson": self.model.poisson,
                "thickness_m": self.model.thickness,
                "density_kg_m3": self.model.density,
                "pretension_n_m": self.model.pretension,
                "foundation_n_m3": self.model.foundation,
                "rigidity_n_m": self.model.rigidity,
            }
        elif isinstance(self.model, Membrane):
            described["material"] = {
                "tension_n_m": self.model.tension,
                "areal_density_kg_m2": self.model.areal_density,
                "wave_speed_m_s": math.sqrt(self.model.tension / self.model.areal_density),
            }
        return described

    def damping_ratios(self, omega: np.ndarray) -> float | np.ndarray:
        """One ratio for every mode (modal damping), or one per mode (Rayleigh)."""
        if not self.damping.is_rayleigh:
            return float(self.damping.zeta)
        return self.damping.ratios(omega)


def _damping(damping: Damping) -> dict[str, float | str]:
    if damping.is_rayleigh:
        return {"kind": "rayleigh", "alpha_per_s": damping.alpha, "beta_s": damping.beta}
    return {"kind": "modal", "zeta": damping.zeta}
