"""A MuJoCo model's grasp sites as the contact's grasps: the tissue held at the site's height.

A grasp (the contact issue's) keeps the tissue's displacement under its footprint at a height,
by a force of either sign: a gripper holding a rope or a fold of skin. Here it is a MuJoCo site
(``<site name=...>`` on the gripper's body): each session step the site's position, where its
velocity takes it by the step's end (as the tools), becomes the grasp's centre and height
(``SceneInfo.to_scene``); the force the session needed, > 0 lifting the tissue, is felt by the
gripper the other way, and applied to the site's body at the site. No shape is involved, so
any placement serves (a rope drawn at 100 times its displacement included).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from membrane_client.errors import UserError
from membrane_client.frame import SceneInfo
from membrane_client.live_schema import Grasp

__all__ = ["GraspSite"]


@dataclass(frozen=True)
class GraspSite:
    """A site of the compiled model that holds the tissue (``radius``: the grasp's footprint,
    scene units; 0 a point, on strings and plates)."""

    name: str
    site: int
    body: int
    radius: float

    @classmethod
    def find(cls, model: Any, name: str, radius: float = 0.0) -> GraspSite:
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
        if site < 0:
            names = [model.site(i).name for i in range(model.nsite) if model.site(i).name]
            raise UserError(f"no site named {name!r} in the model (named sites: {names or 'none'})")
        body = int(model.site_bodyid[site])
        if body == 0:
            raise UserError(f"site {name!r} is on the world body: a grasp needs a body that moves")
        return cls(name, site, body, float(radius))

    def grasp(self, model: Any, data: Any, info: SceneInfo, ahead: float = 0.0) -> Grasp:
        """This site as a grasp, where its velocity takes it in ``ahead`` seconds."""
        position = np.array(data.site_xpos[self.site], dtype=np.float64)
        if ahead:
            velocity = np.zeros(6)
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, self.site, velocity, 0)
            position += ahead * velocity[3:]
        scene, heights = info.to_scene(position)
        return Grasp(tuple(float(c) for c in scene[0]), float(heights[0]), self.radius)
