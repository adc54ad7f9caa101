"""Checking the engine's inputs, ``Load`` and ``Probe``, before anything is computed: finite
values in range, centres of the engine's dimension (a load's in the domain).

The engine takes its own types only; a wire map becomes one in the server, through the client's
live schema, which also owns the per-step limits the protocol states (a test ties these to it).
Fields of other number types (numpy scalars, ints, a list or array for ``at``) are converted.
Messages quote numbers with ``%.6g`` and types by name only, so that nothing a caller passes is
formatted unbounded into an error. Counts are bounded: a step costs at most ``MAX_LOADS`` loads
and ``MAX_PROBES`` probes (the contact problem is solved exactly, by enumeration at worst).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from typing import TypeVar, cast

import numpy as np

from membrane_models.live.errors import (
    InvalidGrasp,
    InvalidLoad,
    InvalidProbe,
    InvalidTool,
    LiveError,
)
from membrane_models.live.interface import TOOL_KINDS, Grasp, Load, Probe, Tool

__all__ = [
    "MAX_DEPTH",
    "MAX_FORCE",
    "MAX_GRASPS",
    "MAX_LOADS",
    "MAX_PROBES",
    "MAX_RADIUS",
    "MAX_TOOLS",
    "MAX_TOOL_POINTS",
    "inside_domain",
    "parse_grasps",
    "parse_loads",
    "parse_probes",
    "parse_tools",
]

MAX_LOADS = 64
MAX_PROBES = 8
MAX_GRASPS = 8
MAX_TOOLS = 4
# Lattice points under one tool: each is a row of the contact problem (a dense solve of at
# most MAX_TOOLS x MAX_TOOL_POINTS unknowns per pivot) and an applied footprint of the state.
MAX_TOOL_POINTS = 64
# Magnitudes in problem units (the domain is 1 long, responses are about 1e-3 per unit force):
# far past any meaningful input, and small enough that no sum of a step can overflow float64
# nor a frame float32.
MAX_FORCE = 1e6
MAX_DEPTH = 1e3
MAX_RADIUS = 10.0  # wider, a Gaussian is uniform over the domain to within 1 %
_Item = TypeVar("_Item", Load, Probe, Grasp, Tool)
_Held = TypeVar("_Held", Probe, Grasp)


def parse_loads(
    loads: Sequence[Load],
    dims: int,
    contains: Callable[[tuple[float, ...]], bool] | None = None,
) -> tuple[Load, ...]:
    """``loads`` as checked ``Load`` objects (finite force, radius >= 0, centre in the domain:
    ``contains``'s, the unit interval or square by default).

    Raises:
        InvalidLoad: what is wrong, and with which load.
    """
    items = _bounded(loads, MAX_LOADS, "loads", InvalidLoad)
    inside = inside_domain if contains is None else contains
    domain = "the unit domain" if inside is inside_domain else "the domain"
    out = []
    for index, item in enumerate(items):
        if (
            type(item) is Load
            and _clean(item.at, dims, item.radius, item.radius)
            and type(item.force) is float
            and -MAX_FORCE <= item.force <= MAX_FORCE
            and inside(item.at)
        ):
            out.append(item)
            continue
        load = _typed(item, Load, f"load {index}", InvalidLoad)
        at = _point(load.at, dims, f"load {index}", InvalidLoad)
        force = _number(load.force, f"load {index} force", InvalidLoad)
        if abs(force) > MAX_FORCE:
            reason = f"|force| must be at most {MAX_FORCE:g}, got {force:.6g}"
            raise InvalidLoad(f"load {index}: {reason}")
        radius = _radius(load.radius, f"load {index}", InvalidLoad)
        if not inside(at):
            raise InvalidLoad(f"load {index}: at {_coords(at)} lies outside {domain}")
        out.append(Load(at, force, radius))
    return tuple(out)


def parse_probes(probes: Sequence[Probe], dims: int) -> tuple[Probe, ...]:
    """``probes`` as checked ``Probe`` objects (|depth| <= MAX_DEPTH: < 0 holds the tip above the
    rest surface; radius >= 0; any finite centre).

    Raises:
        InvalidProbe: what is wrong, and with which probe.
    """
    return _parse_held(probes, Probe, "depth", dims, MAX_PROBES, InvalidProbe)


def inside_domain(at: tuple[float, ...]) -> bool:
    """Whether a point lies in the closed unit interval or square."""
    return all(0.0 <= x <= 1.0 for x in at)


def parse_grasps(grasps: Sequence[Grasp], dims: int) -> tuple[Grasp, ...]:
    """``grasps`` as checked ``Grasp`` objects (|height| <= MAX_DEPTH, radius >= 0; any finite
    centre).

    Raises:
        InvalidGrasp: what is wrong, and with which grasp.
    """
    return _parse_held(grasps, Grasp, "height", dims, MAX_GRASPS, InvalidGrasp)


def parse_tools(tools: Sequence[Tool], dims: int) -> tuple[Tool, ...]:
    """``tools`` as checked ``Tool`` objects (a known kind, |depth| <= MAX_DEPTH, radius > 0 and
    at most MAX_RADIUS; any finite centre).

    Raises:
        InvalidTool: what is wrong, and with which tool.
    """
    out = []
    for index, item in enumerate(_bounded(tools, MAX_TOOLS, "tools", InvalidTool)):
        what = f"tool {index}"
        tool = _typed(item, Tool, what, InvalidTool)
        if type(tool.kind) is not str or tool.kind not in TOOL_KINDS:
            kinds = " or ".join(repr(k) for k in TOOL_KINDS)
            raise InvalidTool(f"{what}: kind must be {kinds}, got {_name(tool.kind)}")
        at = _point(tool.at, dims, what, InvalidTool)
        depth = _number(tool.depth, f"{what} depth", InvalidTool)
        if not -MAX_DEPTH <= depth <= MAX_DEPTH:
            reason = f"depth must be in [-{MAX_DEPTH:g}, {MAX_DEPTH:g}], got {depth:.6g}"
            raise InvalidTool(f"{what}: {reason}")
        radius = _radius(tool.radius, what, InvalidTool)
        if radius == 0.0:
            raise InvalidTool(f"{what}: a rigid tool needs a radius > 0 (a point is a probe)")
        out.append(Tool(tool.kind, at, depth, radius))
    return tuple(out)


def _name(value: object) -> str:
    """A value for a message, bounded: short strings quoted, anything else by type."""
    if type(value) is str and len(value) <= 20:
        return repr(value)
    return type(value).__name__


def _parse_held(
    items: Sequence[_Held],
    kind: type[_Held],
    field: str,
    dims: int,
    limit: int,
    error: type[LiveError],
) -> tuple[_Held, ...]:
    """Probes and grasps alike: ``(at, field, radius)``, ``field`` a signed position along the
    axis within +-MAX_DEPTH, each named "<kind> <index>" in messages."""
    noun = kind.__name__.lower()
    out = []
    for index, item in enumerate(_bounded(items, limit, f"{noun}s", error)):
        if type(item) is kind and _clean(item.at, dims, getattr(item, field), item.radius):
            out.append(cast(_Held, item))  # the haptic loop's case: nothing to convert
            continue
        what = f"{noun} {index}"
        held = _typed(item, kind, what, error)
        at = _point(held.at, dims, what, error)
        value = _number(getattr(held, field), f"{what} {field}", error)
        if not -MAX_DEPTH <= value <= MAX_DEPTH:
            reason = f"{field} must be in [-{MAX_DEPTH:g}, {MAX_DEPTH:g}], got {value:.6g}"
            raise error(f"{what}: {reason}")
        out.append(kind(at, value, _radius(held.radius, what, error)))
    return tuple(out)


def _clean(at: object, dims: int, depth: object, radius: object) -> bool:
    """A dataclass input already in canonical form: float fields, finite, within bounds."""
    return (
        type(at) is tuple
        and len(at) == dims
        and all(type(x) is float and math.isfinite(x) for x in at)
        and type(depth) is float
        and type(radius) is float
        and -MAX_DEPTH <= depth <= MAX_DEPTH
        and 0.0 <= radius <= MAX_RADIUS
    )


def _bounded(
    items: Sequence[object], limit: int, what: str, error: type[LiveError]
) -> Sequence[object]:
    # Exact-type fast paths first (lists and tuples of canonical items): the ABC checks below
    # cost a microsecond each, which a 1 kHz haptic step feels.
    if type(items) is list or type(items) is tuple:
        pass
    elif isinstance(items, str | bytes | Mapping) or not isinstance(items, Sequence):
        raise error(f"{what} must be a list, got {type(items).__name__}")
    if len(items) > limit:
        raise error(f"at most {limit} {what} per step, got {len(items)}")
    return items


def _typed(item: object, kind: type[_Item], what: str, error: type[LiveError]) -> _Item:
    if not isinstance(item, kind):
        raise error(f"{what} must be a {kind.__name__}, got {type(item).__name__}")
    return item


def _number(value: object, what: str, error: type[LiveError]) -> float:
    if type(value) is float and math.isfinite(value):
        return value
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise error(f"{what} must be a number, got {type(value).__name__}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise error(f"{what} must be finite, got {number}")
    return number


def _point(value: object, dims: int, what: str, error: type[LiveError]) -> tuple[float, ...]:
    if type(value) is list and len(value) == dims:
        return tuple(_number(x, f"{what} at", error) for x in value)
    if isinstance(value, np.ndarray) and value.size <= dims:
        value = value.tolist()
    if dims == 1 and not isinstance(value, Sequence):
        return (_number(value, f"{what} at", error),)
    if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) != dims:
        raise error(f"{what}: at must be {dims} coordinate{'s' if dims > 1 else ''}")
    return tuple(_number(x, f"{what} at", error) for x in value)


def _radius(value: object, what: str, error: type[LiveError]) -> float:
    radius = _number(value, f"{what} radius", error)
    if not 0.0 <= radius <= MAX_RADIUS:
        raise error(f"{what}: radius must be >= 0 and at most {MAX_RADIUS:g}, got {radius:.6g}")
    return radius


def _coords(at: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in at) + ")"
