"""The replies with a schema of their own: a scene's description (SceneInfo, the ``describe``
reply) and one served frame (Frame, the ``query`` reply). The server writes them with
``to_reply_fields``, the client reads them with ``from_reply``: one owner for both directions."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from membrane_client import coordinates
from membrane_client.coordinates import Extent, OnceGate
from membrane_client.errors import ProtocolError, UserError
from membrane_client.protocol import pack_array, unpack_array

__all__ = ["AXES", "Frame", "SceneInfo"]

AXES = ("x", "y", "z")


@dataclass(frozen=True, eq=False)
class SceneInfo:
    """A served scene as ``describe`` returns it: the lattice, its placement and its time grid.

    Coordinates and displacements are in the scene's units: problem units for a dimensionless
    scene, SI for a physical one; times in seconds (``units`` says which).
    """

    name: str  # what requests put in ``scene``
    description: str  # one line of text
    points: np.ndarray  # (n, d) float64 lattice coordinates, d = 1 or 2
    shape: tuple[int, ...]  # lattice shape, e.g. (100,) or (20, 20): a frame's ``z`` has it
    dt: float  # the fixed time step
    duration: float  # length of the time domain (frames at steps 0 .. duration / dt)
    start_offset: float  # simulation time at which the response starts
    steps: int  # number of frames, duration / dt + 1
    origin: np.ndarray  # (3,) world position of lattice coordinate 0
    size: float  # world length of one lattice unit
    scale: float  # factor from displacement to world units along ``axis``
    axis: str  # world axis the displacement moves spheres along: 'x', 'y' or 'z'
    policy: str  # out-of-domain policy: 'error', 'clamp' or 'hold'
    snapping: str  # time snapping: 'nearest' or 'linear'
    evaluator: str  # how queries are answered: 'network', 'separable', 'table' or 'exact'
    evaluator_info: dict[str, Any] = field(default_factory=dict)  # its figures (memory, ...)
    model: dict[str, Any] = field(default_factory=dict)  # incl. its measured error
    units: dict[str, Any] = field(default_factory=dict)  # of times, coordinates, displacements
    live: dict[str, Any] = field(default_factory=dict)  # a live scene's engine and limits
    # Names the scene's content: a query reply with another revision means the server reloaded
    # the scene with changes (the client then describes it again).
    revision: str = ""
    # The scene's box in scene coordinates when describe gives one (a physical scene in m: its
    # bounding box); ``extent`` falls back on the lattice's own box.
    declared_extent: Extent | None = None
    # Whether ``query`` serves a film (frames over the time grid); a physical live scene has
    # none: its query answers the rest shape, and only a live session moves it.
    film: bool = True
    # A physical 2-D scene's lattice as a surface: (m, 3) indices into ``points`` of triangles
    # that cover the tissue only (a viewer draws frames on them); None where describe gives none.
    triangles: np.ndarray | None = None
    _outside_warning: OnceGate = field(default_factory=OnceGate, init=False, repr=False)

    @property
    def n_points(self) -> int:
        """Number of lattice points (spheres)."""
        return int(self.points.shape[0])

    @property
    def axis_index(self) -> int:
        """0, 1 or 2 for axis 'x', 'y' or 'z'."""
        return AXES.index(self.axis)

    @property
    def dims(self) -> int:
        """Scene coordinates per point: 1 (a line) or 2 (a surface)."""
        return int(self.points.shape[1])

    @cached_property
    def extent(self) -> Extent:
        """(lower, upper) (d,) arrays: the declared extent, else the lattice points' min/max."""
        if self.declared_extent is not None:
            return self.declared_extent
        return Extent.of_points(self.points)

    def contains(self, scene_point: np.ndarray | tuple[float, ...] | list[float]) -> bool:
        """Whether a (d,) scene point lies in the extent (boundary included)."""
        point = np.asarray(scene_point, dtype=np.float64)
        if point.shape != (self.dims,):
            raise UserError(
                f"a scene point of {self.name} has {self.dims} coordinates, got {point.shape}"
            )
        return bool(self.extent.contains(point[np.newaxis, :])[0])

    def to_scene(
        self, world: np.ndarray | Sequence[float] | Sequence[Sequence[float]]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of ``positions``: (scene points (n, d), heights (n,)) of (3,) or (n, 3)
        world points, height = (world[axis] - origin[axis]) / scale (a tip below the rest plane
        is ``-height`` deep). Warns once per SceneInfo (log and UserWarning) when a point falls
        outside ``extent``: a tool off the tissue usually means a placement is wrong."""
        scene, heights = coordinates.to_scene(
            world, self.origin, self.size, self.scale, self.axis_index, self.dims
        )
        outside = ~self.extent.contains(scene)
        if outside.any() and self._outside_warning.first():
            coordinates.warn_outside(self.name, scene[int(np.argmax(outside))], self.extent)
        return scene, heights

    def times(self) -> np.ndarray:
        """Simulation times of every frame: start_offset + k * dt, k = 0 .. steps - 1."""
        return self.start_offset + np.arange(self.steps, dtype=np.float64) * self.dt

    def rest_positions(self) -> np.ndarray:
        """(n, 3) world coordinates of every sphere at rest (a new array)."""
        return self._rest.copy()

    def positions(self, z: np.ndarray) -> np.ndarray:
        """(n, 3) world coordinates of displacements ``z``: rest plus ``scale * z`` on ``axis``."""
        positions = self.rest_positions()
        positions[:, self.axis_index] += self.scale * np.asarray(z).reshape(-1)
        return positions

    @cached_property
    def _rest(self) -> np.ndarray:
        # Lattice axes go onto the world axes other than the displacement axis, in x, y, z order.
        lateral = coordinates.lateral_axes(self.axis_index, self.dims)
        rest = np.tile(self.origin.astype(np.float64), (self.n_points, 1))
        for column in range(self.dims):
            rest[:, lateral[column]] += self.size * self.points[:, column]
        rest.setflags(write=False)
        return rest

    def to_reply_fields(self) -> dict[str, Any]:
        """The ``describe`` reply's fields (``from_reply`` reads them back)."""
        placement = {"origin": [float(v) for v in self.origin], "size": self.size}
        fields = {
            "scene": self.name,
            "description": self.description,
            "points": pack_array(self.points, "<f8"),
            "shape": list(self.shape),
            "dt": self.dt,
            "duration": self.duration,
            "start_offset": self.start_offset,
            "steps": self.steps,
            "placement": {**placement, "scale": self.scale, "axis": self.axis},
            "policy": self.policy,
            "snapping": self.snapping,
            "evaluator": {"kind": self.evaluator, **self.evaluator_info},
            "model": self.model,
            "units": self.units,
            **({"live": self.live} if self.live else {}),
            # Only when they say something: an older scene's reply, and so its revision, stays.
            **(
                {"extent": self.declared_extent.to_wire()}
                if self.declared_extent is not None
                else {}
            ),
            **({} if self.film else {"film": False}),
            **({} if self.triangles is None else {"triangles": _flat(self.triangles)}),
        }
        return {**fields, "revision": self.revision} if self.revision else fields

    @classmethod
    def from_reply(cls, reply: dict[str, Any]) -> SceneInfo:
        """Build from a ``describe`` reply; raises ProtocolError if a field is missing or wrong."""
        try:
            placement = reply["placement"]
            evaluator = dict(reply["evaluator"])
            points = unpack_array(reply["points"]).astype(np.float64)
            shape = tuple(int(n) for n in reply["shape"])
            origin = np.asarray(placement["origin"], dtype=np.float64)
            extent = _extent_from_reply(reply, points)
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
                live=dict(reply.get("live", {})),
                revision=str(reply.get("revision", "")),
                declared_extent=extent,
                film=_film_from_reply(reply),
                triangles=_triangles_from_reply(reply, points.shape[0]),
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


def _extent_from_reply(reply: dict[str, Any], points: np.ndarray) -> Extent | None:
    """The optional ``extent`` (additive in v1: older replies have none)."""
    if "extent" not in reply:
        return None
    if points.ndim != 2:
        raise ValueError(f"points must be (n, d), got {points.shape}")
    return Extent.from_wire(reply["extent"], int(points.shape[1]))


def _flat(triangles: np.ndarray) -> list[int]:
    return [int(v) for v in np.asarray(triangles).reshape(-1)]


def _triangles_from_reply(reply: dict[str, Any], n_points: int) -> np.ndarray | None:
    """The optional ``triangles`` (additive in v1): a flat list of point indices, three per
    triangle, each below the number of points."""
    flat = reply.get("triangles")
    if flat is None:
        return None
    if type(flat) is not list or len(flat) % 3 or not all(type(v) is int for v in flat):
        raise ValueError("triangles must be a flat list of ints, three per triangle")
    triangles = np.asarray(flat, dtype=np.int32).reshape(-1, 3)
    if triangles.size and (triangles.min() < 0 or triangles.max() >= n_points):
        raise ValueError(f"triangles must index the {n_points} points")
    triangles.setflags(write=False)
    return triangles


def _film_from_reply(reply: dict[str, Any]) -> bool:
    """The optional ``film`` (additive in v1: older replies have none, and a film)."""
    film = reply.get("film", True)
    if type(film) is not bool:
        raise ValueError(f"film must be a bool, got {film!r:.64}")
    return film


@dataclass(frozen=True, eq=False)
class Frame:
    """One served frame."""

    t: float  # the time served, s (the step's time under nearest snapping)
    step: int  # the step index served
    z: np.ndarray  # displacement shaped like the lattice (read-only); float32 unless asked
    requested_t: float  # the time the query asked for
    domain: str  # 'inside', 'clamped' or 'held': how the scene's policy treated the time
    scene: str  # the scene's name
    info: SceneInfo | None = None  # the scene's description, for ``positions()``
    revision: str = ""  # the scene's revision that served it ("" from older servers)

    def positions(self) -> np.ndarray:
        """(n, 3) world coordinates: rest position plus ``scale * z`` along the scene's axis."""
        if self.info is None:
            raise UserError("this frame carries no SceneInfo; positions() needs describe()")
        return self.info.positions(self.z)

    def to_reply_fields(self, dtype: str = "<f4", *, requested: bool = True) -> dict[str, Any]:
        """The ``query`` reply's fields, z as ``dtype``; without ``requested_t`` when not
        ``requested`` (the server caches a step's fields and adds the time each request asked)."""
        fields = {
            "scene": self.scene,
            "revision": self.revision,
            "t": self.t,
            "step": self.step,
            "domain": self.domain,
            "z": pack_array(self.z, dtype),
        }
        return {**fields, "requested_t": self.requested_t} if requested else fields

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
