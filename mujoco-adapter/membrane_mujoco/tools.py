"""A MuJoCo model's tool geoms as the contact's rigid tools, and their forces back.

A sphere geom is a ``sphere`` tool of its radius; a cylinder geom is a ``cylinder`` (a flat
punch) of its radius, its axis along the scene's displacement axis (within ``ALIGNED_RAD``):
the live contact presses along that axis only. Other geom types are refused with the reason.

Signs and units: the tissue's displacement is along +axis (``describe``'s placement), tools
press from the +axis side, a tool's ``depth`` is how far its lowest point is below the rest
surface (``SceneInfo.to_scene``'s height, negated). Lengths map through the placement: a rigid
shape stays a sphere or a cylinder in the scene only when the placement's ``scale`` (along the
axis) equals its ``size`` (across it), so other placements are refused. A reading's force
(>= 0, pushing the tool along +axis) is in the scene's force unit: N on an SI scene, times
``force_scale`` (N per problem unit) on a dimensionless one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from membrane_client.coordinates import lateral_axes
from membrane_client.errors import UserError
from membrane_client.frame import SceneInfo
from membrane_client.live_schema import Tool

__all__ = ["ALIGNED_RAD", "ToolGeom", "check_rigid_placement", "force_scale_of", "wrench"]

ALIGNED_RAD = 1e-3  # a cylinder tilted more than this from the press axis is refused
_SHAPES = {
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}


@dataclass(frozen=True)
class ToolGeom:
    """A geom of the compiled model that presses the tissue.

    Attributes:
        name: the geom's name; geom, body: their ids.
        kind: "sphere" or "cylinder"; radius: its radius (m, world);
        reach: from its centre to its lowest point along the axis (the sphere's radius, the
            cylinder's half-length).
    """

    name: str
    geom: int
    body: int
    kind: str
    radius: float
    reach: float

    @classmethod
    def find(cls, model: Any, name: str) -> ToolGeom:
        """The geom named ``name``; ``UserError`` naming the geoms there are, or the reason its
        type cannot press."""
        geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if geom < 0:
            names = [model.geom(i).name for i in range(model.ngeom) if model.geom(i).name]
            raise UserError(f"no geom named {name!r} in the model (named geoms: {names or 'none'})")
        kind = _SHAPES.get(int(model.geom_type[geom]))
        if kind is None:
            shape = mujoco.mjtGeom(int(model.geom_type[geom])).name.removeprefix("mjGEOM_").lower()
            raise UserError(
                f"geom {name!r} is a {shape}: a tool is a sphere or a cylinder (the live "
                f"contact's rigid shapes); give the tool a sphere or cylinder geom"
            )
        size = model.geom_size[geom]
        reach = float(size[0] if kind == "sphere" else size[1])
        return cls(name, geom, int(model.geom_bodyid[geom]), kind, float(size[0]), reach)

    def tool(self, model: Any, data: Any, info: SceneInfo, ahead: float = 0.0) -> Tool:
        """This geom as a live tool in the scene's coordinates, where its velocity now takes it
        in ``ahead`` seconds (0: where it is)."""
        axis = info.axis_index
        centre = np.array(data.geom_xpos[self.geom], dtype=np.float64)
        if ahead:
            velocity = np.zeros(6)  # rotational, then linear, in the world frame
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_GEOM, self.geom, velocity, 0)
            centre += ahead * velocity[3:]
        if self.kind == "cylinder":
            along = np.asarray(data.geom_xmat[self.geom], dtype=np.float64).reshape(3, 3)[:, 2]
            tilt = math.acos(min(1.0, abs(float(along[axis]))))
            if tilt > ALIGNED_RAD:
                raise UserError(
                    f"cylinder {self.name!r} is tilted {math.degrees(tilt):.3g} deg from the "
                    f"scene's press axis {info.axis!r}: the live contact presses a flat punch "
                    f"along that axis only"
                )
        lowest = centre.copy()
        lowest[axis] -= self.reach
        scene, heights = info.to_scene(lowest)
        return Tool(self.kind, tuple(float(c) for c in scene[0]), -float(heights[0]),
                    self.radius / info.size)  # fmt: skip


def check_rigid_placement(info: SceneInfo) -> None:
    """Refuse a placement that would not keep a rigid tool's shape in the scene."""
    if not math.isclose(info.scale, info.size, rel_tol=1e-12):
        raise UserError(
            f"scene {info.name!r} is placed with scale {info.scale:g} along its axis and size "
            f"{info.size:g} across it: a rigid tool would not keep its shape in the scene; "
            f"press with tools on a scene placed with scale = size (the SI scenes are), or "
            f"hold it with grasps"
        )


def force_scale_of(info: SceneInfo, force_scale: float | None) -> float:
    """N per scene force unit: 1 on an SI scene (or ``force_scale``); ``force_scale`` on a
    dimensionless one, where it is required."""
    if info.units.get("force") == "N":
        return 1.0 if force_scale is None else float(force_scale)
    if force_scale is None or not (math.isfinite(force_scale) and force_scale > 0):
        raise UserError(
            f"scene {info.name!r} is dimensionless: give force_scale (N per problem unit of "
            f"force, > 0) to turn its forces into the model's"
        )
    return float(force_scale)


def wrench(
    force: float, point: np.ndarray, body_com: np.ndarray, info: SceneInfo, scale: float
) -> np.ndarray:
    """``xfrc_applied``'s row (force, then torque about the body's centre of mass, world frame)
    for ``force`` along +axis in the scene's unit (``scale``: N per unit), acting at the scene
    point ``point`` (its height does not matter: the force is along the axis)."""
    if force == 0.0:
        return np.zeros(6)
    vector = np.zeros(3)
    vector[info.axis_index] = scale * force
    where = np.array(body_com, dtype=np.float64)
    lateral = lateral_axes(info.axis_index, info.dims)
    where[lateral] = info.origin[lateral] + info.size * np.asarray(point)
    return np.concatenate([vector, np.cross(where - body_com, vector)])
