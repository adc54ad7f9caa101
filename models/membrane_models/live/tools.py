"""Rigid tools as constraint points: the lattice points under each tool and its surface there.

A tool (``interface.Tool``) keeps the tissue at or below its surface at every lattice point
under it: the points a frame shows, so that no frame the engine gives is ever above a tool by
more than rounding. Only points the tissue can move at count (a clamped or outside point stays
at 0 whatever presses it). Over a point at horizontal distance rho from the centre the surface
is, along +axis (a tool presses along -axis, its lowest point ``depth`` below the rest surface),

    sphere of radius R:    -depth + R - sqrt(R^2 - rho^2),   rho <= R,
    cylinder of radius R:  -depth,                           rho <= R,

and a point under two tools takes the lower surface (the tighter constraint, whose tool it
then belongs to). On a string rho is |x - a|: the sphere is a circle across the rope, the
cylinder a flat segment of half-width R.

Between lattice points the tissue is not constrained: a tool narrower than the lattice's
spacing may touch no point (its reading says so: ``points`` 0) and a curved tool's surface may
dip between points by up to its sag over half a spacing (sphere: about s^2 / (8 R)).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.errors import InvalidTool
from membrane_models.live.interface import Tool, ToolReading

__all__ = ["ToolPoints", "tool_points", "tool_readings", "tool_surface"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
_NAN = float("nan")


@dataclass(frozen=True)
class ToolPoints:
    """The contact problem's rows: lattice points under the tools.

    Attributes:
        indices: the points' lattice indices (x-major, flattened), each once.
        coordinates: their centres, (points, dims), in the basis's length unit.
        surface: the lowest tool surface over each point (a height along +axis).
        owner: the tool each point's surface belongs to (its index in the step's tools).
    """

    indices: IntArray
    coordinates: FloatArray
    surface: FloatArray
    owner: IntArray

    @property
    def count(self) -> int:
        return int(self.indices.size)


def tool_surface(tool: Tool, rho: FloatArray) -> FloatArray:
    """The tool's surface height (along +axis) over points at distances ``rho`` <= radius."""
    if tool.kind == "cylinder":
        return np.full(rho.shape, -tool.depth)
    radius = tool.radius
    return -tool.depth + radius - np.sqrt(np.maximum(radius * radius - rho * rho, 0.0))


def tool_points(
    tools: Sequence[Tool],
    coordinates: FloatArray,
    movable: NDArray[np.bool_],
    max_points: int,
) -> ToolPoints:
    """The lattice points under ``tools`` (``coordinates`` of every lattice point, ``movable``
    marking those the tissue can move at), at most ``max_points`` per tool.

    Raises:
        InvalidTool: a tool covering more than ``max_points`` points.
    """
    surface = np.full(coordinates.shape[0], np.inf)
    owner = np.full(coordinates.shape[0], -1, dtype=np.intp)
    for index, tool in enumerate(tools):
        rho = np.sqrt(((coordinates - np.asarray(tool.at)) ** 2).sum(axis=1))
        under = np.flatnonzero(movable & (rho <= tool.radius))
        if under.size > max_points:
            raise InvalidTool(
                f"tool {index}: it covers {under.size} lattice points, more than the "
                f"{max_points} a tool may (describe's live.max_tool_points): use a smaller "
                "tool or a coarser lattice"
            )
        height = tool_surface(tool, rho[under])
        lower = height < surface[under]
        surface[under[lower]] = height[lower]
        owner[under[lower]] = index
    chosen = np.flatnonzero(owner >= 0)
    return ToolPoints(chosen, coordinates[chosen], surface[chosen], owner[chosen])


def tool_readings(
    tools: Sequence[Tool],
    points: ToolPoints,
    forces: FloatArray,
    displacement: FloatArray,
) -> tuple[ToolReading, ...]:
    """Each tool's reading from its points' contact ``forces`` and end-of-step
    ``displacement``s."""
    if len(tools) == 1:  # every point is the tool's: no masks (a haptic press's every step)
        return (_reading(tools[0], forces, points.coordinates, points.surface - displacement),)
    readings = []
    for index, tool in enumerate(tools):
        mine = points.owner == index
        clearance = points.surface[mine] - displacement[mine]
        readings.append(_reading(tool, forces[mine], points.coordinates[mine], clearance))
    return tuple(readings)


def _reading(
    tool: Tool, force: FloatArray, coordinates: FloatArray, clearance: FloatArray
) -> ToolReading:
    """One tool's reading from its points' forces, centres and clearances."""
    if not force.size:
        return ToolReading(0.0, tool.at, 0, 0, _NAN, _NAN)
    total = float(force.sum())
    centre = tuple((force @ coordinates / total).tolist()) if total > 0.0 else tool.at
    lowest = float(clearance.min())
    contacts = int(np.count_nonzero(force > 0.0))
    gap = 0.0 if contacts else max(lowest, 0.0)
    return ToolReading(total, centre, contacts, int(force.size), gap, max(-lowest, 0.0))
