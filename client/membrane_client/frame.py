"""What the client hands back: a scene's description (SceneInfo) and one served frame (Frame)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from membrane_client.errors import ProtocolError, UserError
from membrane_client.protocol import unpack_array

__all__ = ["AXES", "Frame", "SceneInfo"]

AXES = ("x", "y", "z")


@dataclass(frozen=True, eq=False)
class SceneInfo:
    """A served scene as ``describe`` returns it: the lattice, its placement and its time grid.

    Attributes:
        name: Scene name (what requests put in ``scene``).
        description: One line of text.
        points: (n, d) float64 lattice coordinates in problem units (d = 1 or 2).
        shape: Lattice shape, e.g. (100,) or (20, 20); a frame's ``z`` has this shape.
        dt: Fixed time step, seconds.
        duration: Length of the time domain, seconds (frames at steps 0 .. duration / dt).
        start_offset: Simulation time at which the response starts, seconds.
        steps: Number of frames (duration / dt + 1).
        origin: (3,) world position of lattice coordinate 0.
        size: World length of one lattice unit.
        scale: Factor from displacement (problem units) to world units along ``axis``.
        axis: World axis the displacement moves spheres along ('x', 'y' or 'z').
        policy: Out-of-domain policy ('error', 'clamp' or 'hold').
        snapping: Time-snapping rule ('nearest' or 'linear').
        evaluator: How the server answers queries ('network', 'separable', 'table', 'exact').
        evaluator_info: The evaluator's own figures (memory, rank, ...).
        model: Model summary, including its measured error against the exact solution.
        units: Units of times, coordinates and displacements.
        revision: Names the scene's content: a query reply with another revision means the
            server reloaded the scene with changes (the client then describes it again).
    """

    name: str
    description: str
    points: np.ndarray
    shape: tuple[int, ...]
    dt: float
    duration: float
    start_offset: float
    steps: int
    origin: np.ndarray
    size: float
    scale: float
    axis: str
    policy: str
    snapping: str
    evaluator: str
    evaluator_info: dict[str, Any] = field(default_factory=dict)
    model: dict[str, Any] = field(default_factory=dict)
    units: dict[str, Any] = field(default_factory=dict)
    revision: str = ""

    @property
    def n_points(self) -> int:
        """Number of lattice points (spheres)."""
        return int(self.points.shape[0])

    @property
    def axis_index(self) -> int:
        """0, 1 or 2 for axis 'x', 'y' or 'z'."""
        return AXES.index(self.axis)

    def times(self) -> np.ndarray:
        """Simulation times of every frame: start_offset + k * dt, k = 0 .. steps - 1."""
        return self.start_offset + np.arange(self.steps, dtype=np.float64) * self.dt

    def rest_positions(self) -> np.ndarray:
        """(n, 3) world coordinates of every sphere at rest (a new array)."""
        return self._rest.copy()

    @cached_property
    def _rest(self) -> np.ndarray:
        # Lattice axes go onto the world axes other than the displacement axis, in x, y, z order.
        lateral = [i for i in range(3) if i != self.axis_index]
        rest = np.tile(self.origin.astype(np.float64), (self.n_points, 1))
        for column in range(self.points.shape[1]):
            rest[:, lateral[column]] += self.size * self.points[:, column]
        rest.setflags(write=False)
        return rest

    @classmethod
    def from_reply(cls, reply: dict[str, Any]) -> SceneInfo:
        """Build from a ``describe`` reply; raises ProtocolError if a field is missing or wrong."""
        try:
            placement = reply["placement"]
            evaluator = dict(reply["evaluator"])
            points = unpack_array(reply["points"]).astype(np.float64)
            shape = tuple(int(n) for n in reply["shape"])
            origin = np.asarray(placement["origin"], dtype=np.float64)
            info = cls(
                name=str(reply["scene"]),
                description=str(reply.get("description", "")),
                points=points,
                shape=shape,
                dt=float(reply["dt"]),
                duration=float(reply["duration"]),
                start_offset=float(reply["start_offset"]),
                steps=int(reply["steps"]),
                origin=origin,
                size=float(placement["size"]),
                scale=float(placement["scale"]),
                axis=str(placement["axis"]),
                policy=str(reply["policy"]),
                snapping=str(reply["snapping"]),
                evaluator=str(evaluator.pop("kind")),
                evaluator_info=evaluator,
                model=dict(reply.get("model", {})),
                units=dict(reply.get("units", {})),
                revision=str(reply.get("revision", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"malformed describe reply: {exc!r}") from None
        info._check()
        return info

    def _check(self) -> None:
        problem = None
        if self.points.ndim != 2 or self.points.shape[1] not in (1, 2):
            problem = f"points must be (n, 1) or (n, 2), got {self.points.shape}"
        elif int(np.prod(self.shape)) != self.n_points:
            problem = f"shape {self.shape} does not hold {self.n_points} points"
        elif self.origin.shape != (3,):
            problem = f"origin must have 3 coordinates, got {self.origin.shape}"
        elif self.axis not in AXES:
            problem = f"axis must be x, y or z, got {self.axis!r}"
        if problem is not None:
            raise ProtocolError(f"malformed describe reply: {problem}")


@dataclass(frozen=True, eq=False)
class Frame:
    """One served frame.

    Attributes:
        t: The time served, seconds (the step time under nearest snapping).
        step: The step index served.
        z: Displacement shaped like the lattice (read-only), in problem units; float32
            unless the query asked for float64.
        requested_t: The time the query asked for.
        domain: 'inside', 'clamped' or 'held' (how the scene's policy treated the time).
        scene: Scene name.
        info: The scene's description, used by ``positions()``.
        revision: The scene's revision that served this frame ("" from servers without one).
    """

    t: float
    step: int
    z: np.ndarray
    requested_t: float
    domain: str
    scene: str
    info: SceneInfo | None = None
    revision: str = ""

    def positions(self) -> np.ndarray:
        """(n, 3) world coordinates: rest position plus ``scale * z`` along the scene's axis."""
        if self.info is None:
            raise UserError("this frame carries no SceneInfo; positions() needs describe()")
        positions = self.info.rest_positions()
        positions[:, self.info.axis_index] += self.info.scale * self.z.reshape(-1)
        return positions

    @classmethod
    def from_reply(cls, reply: dict[str, Any], info: SceneInfo | None = None) -> Frame:
        """Build from a ``query`` reply; raises ProtocolError if a field is missing or wrong."""
        try:
            frame = cls(
                t=float(reply["t"]),
                step=int(reply["step"]),
                z=unpack_array(reply["z"]),
                requested_t=float(reply.get("requested_t", reply["t"])),
                domain=str(reply.get("domain", "inside")),
                scene=str(reply["scene"]),
                info=info,
                revision=str(reply.get("revision", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"malformed query reply: {exc!r}") from None
        if info is not None and frame.z.size != info.n_points:
            raise ProtocolError(f"query: {frame.z.size} displacements for {info.n_points} points")
        return frame
