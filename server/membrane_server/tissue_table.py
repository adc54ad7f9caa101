"""A scene's ``[tissue]`` table: a physical tissue in SI units instead of a dimensionless problem.

The table names the shape, the material, the supports, the damping, the modes and the
footprint radii sessions may use (docs/SCENES.md, "Physical scenes"); ``TissueTable.build``
meshes it and returns the ``membrane_models.fem.Tissue`` the ``fem`` engine steps. Units: m,
Pa, kg/m^3, N/m, N/m^3, s. Every error names its field (a ``SceneError`` once the scene wraps
it); what the fem room refuses (a shape it cannot mesh, a model with rigid-body modes) comes
back as its own one-line message.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, model_validator

from membrane_models.fem import (
    Damping,
    Domain,
    Membrane,
    Plate,
    disk,
    ellipse,
    polygon,
    read_mesh,
    rectangle,
)
from membrane_models.fem.models import Model
from membrane_models.fem.tissue import Tissue

__all__ = ["MAX_TISSUE_MODES", "TissueTable"]

MAX_TISSUE_MODES = 400  # modes a tissue scene may step (its tables grow with them)
_MAX_RADII = 4  # footprint radii per tissue (a cross table per pair)
_Supports = Literal["clamped", "simply_supported", "free"]


class TissueTable(BaseModel):
    """The ``[tissue]`` table (module docstring)."""

    # Unknown keys are typos; NaN and infinities are never meaningful; numbers stay numbers.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)

    name: str = Field(default="tissue", max_length=80)
    kind: Literal["plate", "membrane"] = "plate"
    shape: Literal["rectangle", "disk", "ellipse", "polygon", "mesh"] = "rectangle"
    # rectangle: [width, height]; disk: [diameter]; ellipse: [x axis, y axis] (full lengths)
    size: list[StrictFloat] | None = Field(default=None, min_length=1, max_length=2)
    vertices: list[list[StrictFloat]] | None = None  # polygon, m
    holes: list[list[list[StrictFloat]]] = Field(default_factory=list)
    mesh: str | None = None  # a .msh or .vtk file, relative to the scene's folder
    element_size: float = Field(gt=0.0, le=1.0)
    # a plate's material
    youngs_modulus: float | None = Field(default=None, gt=0.0)
    poisson: float | None = Field(default=None, gt=-1.0, le=0.5)
    thickness: float | None = Field(default=None, gt=0.0)
    density: float | None = Field(default=None, gt=0.0)
    pretension: float = Field(default=0.0, ge=0.0)
    foundation: float = Field(default=0.0, ge=0.0)
    # a membrane's
    tension: float | None = Field(default=None, gt=0.0)
    areal_density: float | None = Field(default=None, gt=0.0)
    supports: _Supports | dict[str, _Supports] = "clamped"
    damping: float = Field(default=0.0, ge=0.0, lt=1.0)  # modal ratio zeta
    rayleigh: list[StrictFloat] | None = Field(default=None, min_length=2, max_length=2)
    modes: int = Field(default=100, ge=1, le=MAX_TISSUE_MODES)
    radii: list[StrictFloat] = Field(default=[0.0], min_length=1, max_length=_MAX_RADII)

    @model_validator(mode="after")
    def _consistent(self) -> TissueTable:
        if self.kind == "plate":
            missing = [n for n in ("youngs_modulus", "poisson", "thickness", "density")
                       if getattr(self, n) is None]  # fmt: skip
            if missing:
                raise ValueError(f"a plate needs {', '.join(missing)}")
            if self.tension is not None or self.areal_density is not None:
                raise ValueError("a plate takes pretension (N/m), not tension / areal_density")
        else:
            if self.tension is None or self.areal_density is None:
                raise ValueError("a membrane needs tension (N/m) and areal_density (kg/m^2)")
            if 0.0 in self.radii:
                raise ValueError(
                    "radii: a point force (0) on a membrane has an infinite displacement under "
                    "it; give footprint radii > 0"
                )
        if any(not (math.isfinite(r) and 0.0 <= r <= 0.1) for r in self.radii):
            raise ValueError("radii must be from 0 to 0.1 m")
        if self.damping > 0 and self.rayleigh is not None:
            raise ValueError("damping is modal (damping) or Rayleigh (rayleigh), not both")
        if self.rayleigh is not None and min(self.rayleigh) < 0:
            raise ValueError("rayleigh [alpha, beta] must be >= 0")
        self._check_shape()
        return self

    def _check_shape(self) -> None:
        needs_size = {"rectangle": 2, "disk": 1, "ellipse": 2}
        if self.shape in needs_size:
            count = needs_size[self.shape]
            if self.size is None or len(self.size) != count or min(self.size) <= 0:
                raise ValueError(f"a {self.shape} needs size = [{count} length(s) > 0 in m]")
        elif self.shape == "polygon" and not self.vertices:
            raise ValueError("a polygon needs vertices = [[x, y], ...] (m)")
        elif self.shape == "mesh" and not self.mesh:
            raise ValueError("shape 'mesh' needs mesh = 'file.msh' (or .vtk)")

    def build(self, folder: Path | None) -> Tissue:
        """Mesh the shape and return the tissue (``folder``: where a relative mesh file is).

        Raises:
            FemError: the fem room's refusal (one line), e.g. a shape it cannot mesh.
        """
        domain = self._domain(folder)
        damping = Damping.rayleigh(*self.rayleigh) if self.rayleigh else Damping.modal(self.damping)
        return Tissue(
            name=self.name,
            domain=domain,
            model=self._model(),
            supports=self.supports,
            damping=damping,
            modes=self.modes,
            radii=tuple(float(r) for r in self.radii),
            shape=self._shape_description(),
        )

    def _model(self) -> Model:
        if self.kind == "membrane":
            assert self.tension is not None and self.areal_density is not None
            return Membrane(tension=self.tension, areal_density=self.areal_density)
        assert self.youngs_modulus is not None and self.poisson is not None
        assert self.thickness is not None and self.density is not None
        return Plate(
            youngs_modulus=self.youngs_modulus,
            poisson=self.poisson,
            thickness=self.thickness,
            density=self.density,
            pretension=self.pretension,
            foundation=self.foundation,
        )

    def _domain(self, folder: Path | None) -> Domain:
        h = self.element_size
        if self.shape == "rectangle":
            assert self.size is not None
            return rectangle(self.size[0], self.size[1], h)
        if self.shape == "disk":
            assert self.size is not None
            return disk(self.size[0] / 2, h, (self.size[0] / 2, self.size[0] / 2))
        if self.shape == "ellipse":
            assert self.size is not None
            a, b = self.size[0] / 2, self.size[1] / 2
            return ellipse(a, b, h, (a, b))
        if self.shape == "polygon":
            assert self.vertices is not None
            return polygon(self.vertices, h, holes=self.holes)
        assert self.mesh is not None
        path = Path(self.mesh)
        return read_mesh(path if path.is_absolute() or folder is None else folder / path)

    def _shape_description(self) -> dict[str, object]:
        described: dict[str, object] = {"kind": self.shape, "element_size_m": self.element_size}
        if self.size is not None:
            described["size_m"] = list(self.size)
        if self.mesh is not None:
            described["mesh"] = self.mesh
        return described
