"""A MuJoCo model coupled to a live session, one session step at a time.

```python
spec = mujoco.MjSpec.from_file("examples/mujoco/press.xml")
with Client(address) as client, client.session("skin-patch") as session:
    coupler = Coupler(spec, session, tools=["tip"])   # adds the lattice, compiles
    for _ in range(2000):
        step = coupler.step()                          # 1 ms: the tissue, then MuJoCo
```

The coupling scheme, explicit with a predicted tool: at the start of each session step every
tool geom is sent to the session where its velocity takes it by the step's end (its pose plus
dt times its velocity, ``ToolGeom.tool``); the session steps the tissue so that it meets the
tool there and reports each tool's contact force; that force (with its moment about the tool
body's centre of mass) is applied to the tool body through ``xfrc_applied`` during the MuJoCo
steps that follow, ``substeps`` of them spanning the scene's dt (``timing``). So the force
MuJoCo feels during a step is the one computed at that step's start, for where the tool will
be at its end. Why predicted: a rigid contact on the tissue is stiff over one step
(skin-patch: about 981 N/m, against 302 N/m static), and sent where it was at the step's start
a 10 g tool dropped on the patch gained energy at every bounce and flew off (the lag acts as a
negative damping of about that stiffness times dt); sent where it will be, it settles on the
patch under m g (``tests/mujoco``). ``xfrc_applied`` is the coupler's to write on the tool
bodies (it overwrites their rows each step); the rest of the model is the user's.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from membrane_client.errors import UserError
from membrane_client.live_schema import Grasp, Tool
from membrane_client.session import LiveFrame, Session
from membrane_mujoco.grasps import GraspSite
from membrane_mujoco.lattice import Lattice, add_lattice
from membrane_mujoco.timing import substeps
from membrane_mujoco.tools import ToolGeom, check_rigid_placement, force_scale_of, wrench

__all__ = ["CoupledStep", "Coupler"]


@dataclass(frozen=True)
class CoupledStep:
    """One session step and the MuJoCo steps it spanned.

    Attributes:
        frame: the session's reply (``tools``: each tool's reading; ``z`` when drawn).
        tools, grasps: as sent (where each geom's or site's velocity took it by the step's end).
        forces: (tools + grasps, 6) what was applied to each body, world frame (N, N m).
        session_s, mujoco_s: wall seconds in the session step and in MuJoCo's steps.
    """

    frame: LiveFrame
    tools: tuple[Tool, ...]
    grasps: tuple[Grasp, ...]
    forces: np.ndarray
    session_s: float
    mujoco_s: float


class Coupler:
    """A MuJoCo model and a live session, coupled (module docstring).

    Args:
        spec: the user's model, not yet compiled (``mujoco.MjSpec``): the lattice is added to it.
        session: an open live session (its ``info`` from ``describe``).
        tools: the names of the geoms that press the tissue.
        grasps: the names of the sites that hold it (``grasps``).
        draw: add and move the lattice's spheres (False: no frame is asked for).
        force_scale: N per problem unit of force, on a dimensionless scene only.
    """

    def __init__(
        self,
        spec: Any,
        session: Session,
        tools: Sequence[str] = (),
        *,
        grasps: Sequence[str] = (),
        draw: bool = True,
        force_scale: float | None = None,
    ) -> None:
        info = session.info
        if info is None or not info.live:
            raise UserError("the session's scene is not live: nothing to couple")
        if not tools and not grasps:
            raise UserError("name at least one tool geom or grasp site")
        if tools:
            check_rigid_placement(info)
        self.session, self.info = session, info
        self.force_scale = force_scale_of(info, force_scale)
        self.substeps = substeps(float(spec.option.timestep), info.dt)
        if draw:
            add_lattice(spec, info)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.tools = [ToolGeom.find(self.model, name) for name in tools]
        self.grasps = [GraspSite.find(self.model, name) for name in grasps]
        bodies = [tool.body for tool in self.tools] + [grasp.body for grasp in self.grasps]
        if len(set(bodies)) != len(bodies) or 0 in bodies:
            raise UserError("each tool geom and grasp site needs a body of its own (not the world)")
        self.bodies = np.array(bodies, dtype=np.int64)  # tools' then grasps', as ``forces``
        self.lattice = Lattice.bind(self.model, info) if draw else None
        if self.lattice is not None:
            self.lattice.show(self.model, self.data, info, np.zeros(info.n_points))
        mujoco.mj_forward(self.model, self.data)

    @property
    def time(self) -> float:
        """MuJoCo's simulation time (s)."""
        return float(self.data.time)

    def step(self) -> CoupledStep:
        """One session step with the tools and grasps where they will be at its end, then its
        MuJoCo substeps under the forces it reported."""
        model, data, info = self.model, self.data, self.info
        mujoco.mj_kinematics(model, data)  # poses and velocities at this step's start
        mujoco.mj_comPos(model, data)
        mujoco.mj_comVel(model, data)
        tools = [tool.tool(model, data, info, info.dt) for tool in self.tools]
        grasps = [grasp.grasp(model, data, info, info.dt) for grasp in self.grasps]
        began = time.perf_counter()
        frame = self.session.step(tools=tools, grasps=grasps, frame=self.lattice is not None)
        session_s = time.perf_counter() - began
        scale = self.force_scale
        rows = [  # a tool is pushed along +axis; a gripper feels its grasp's force reversed
            wrench(reading.force, np.asarray(reading.centre), data.xipos[tool.body], info, scale)
            for tool, reading in zip(self.tools, frame.tools, strict=True)
        ] + [
            wrench(-reading.force, np.asarray(sent.at), data.xipos[grasp.body], info, scale)
            for grasp, sent, reading in zip(self.grasps, grasps, frame.grasps, strict=True)
        ]
        forces = np.array(rows).reshape(-1, 6)
        data.xfrc_applied[self.bodies] = forces
        began = time.perf_counter()
        for _ in range(self.substeps):
            mujoco.mj_step(model, data)
        mujoco_s = time.perf_counter() - began
        if self.lattice is not None and frame.z is not None:
            self.lattice.show(model, data, info, frame.z)
        return CoupledStep(frame, tuple(tools), tuple(grasps), forces, session_s, mujoco_s)
