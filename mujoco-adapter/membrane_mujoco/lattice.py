"""The tissue drawn in a MuJoCo model: one mocap sphere per lattice point, visual only.

The tissue's physics is the session's: the spheres collide with nothing (``contype`` and
``conaffinity`` 0) and weigh nothing the simulation sees (mocap bodies are not simulated).
They are added to the user's model through ``mjSpec`` before it is compiled (a compiled model
cannot grow), and moved and coloured each session step: the colour runs from the rest colour to
the pressed one over ``colour_depth`` of displacement along -axis (the dent a tool makes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from membrane_client.frame import SceneInfo

__all__ = ["Lattice", "add_lattice"]

PREFIX = "membrane_lattice_"
REST_RGBA = np.array([0.85, 0.62, 0.55, 1.0])  # skin
PRESSED_RGBA = np.array([0.55, 0.05, 0.10, 1.0])


def add_lattice(spec: Any, info: SceneInfo, radius: float | None = None) -> None:
    """Add the lattice's spheres to ``spec`` at their rest positions (``radius``: world units;
    None: 0.35 of the lattice spacing)."""
    rest = info.positions(np.zeros(info.n_points))
    size = _spacing(info) * 0.35 if radius is None else radius
    for index, position in enumerate(rest):
        body = spec.worldbody.add_body(name=f"{PREFIX}{index}", mocap=True, pos=position.tolist())
        body.add_geom(
            name=f"{PREFIX}geom_{index}",
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[size, 0.0, 0.0],
            contype=0,
            conaffinity=0,
            rgba=REST_RGBA.tolist(),
        )


@dataclass(frozen=True)
class Lattice:
    """The spheres of a compiled model: their mocap slots and geoms."""

    mocap: np.ndarray  # (n,) mocap ids, in lattice order
    geoms: np.ndarray  # (n,) geom ids
    colour_depth: float  # displacement (scene units) drawn in the pressed colour

    @classmethod
    def bind(cls, model: Any, info: SceneInfo, colour_depth: float | None = None) -> Lattice:
        bodies = [model.body(f"{PREFIX}{i}").id for i in range(info.n_points)]
        mocap = np.array([model.body_mocapid[b] for b in bodies])
        geoms = np.array([model.geom(f"{PREFIX}geom_{i}").id for i in range(info.n_points)])
        depth = colour_depth if colour_depth is not None else 0.02 * _extent(info) / info.scale
        return cls(mocap, geoms, depth)

    def show(self, model: Any, data: Any, info: SceneInfo, z: np.ndarray) -> None:
        """Move the spheres to displacements ``z`` and colour them by depth."""
        data.mocap_pos[self.mocap] = info.positions(z)
        dent = np.clip(-np.asarray(z, dtype=np.float64).reshape(-1) / self.colour_depth, 0, 1)
        model.geom_rgba[self.geoms] = REST_RGBA + dent[:, None] * (PRESSED_RGBA - REST_RGBA)


def _spacing(info: SceneInfo) -> float:
    """The lattice's smallest spacing in world units."""
    points = info.points
    gaps = [np.diff(np.unique(points[:, d])) for d in range(info.dims)]
    return float(min(g[g > 0].min() for g in gaps if g.size)) * info.size


def _extent(info: SceneInfo) -> float:
    return float(np.ptp(info.points, axis=0).max()) * info.size
