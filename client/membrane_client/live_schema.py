"""The live session's wire schema (docs/PROTOCOL.md, "Live sessions"): loads, probes, grasps,
rigid tools, their readings, an open's initial shapes, the replies of open, step, read, reset
and close, and the per-step limits. Defined once, here, and used by both sides.

A client builds items with ``to_wire`` and reads replies with ``from_reply``; the server reads
items with ``from_wire`` (every check of the map's form: exact keys, numbers that are neither
bools nor strings, ``at`` of the scene's dimension, all finite) and writes replies with
``to_reply_fields``. The ranges (a force's magnitude, a depth, a radius, a centre in the domain)
are the engine's to check: they depend on the engine, and direct callers of an engine need them
too. Messages quote a peer's values through ``codec.preview`` (at most 64 characters), so that
one stays within an error reply's 300.

A field added to a load, a probe or a reply is added here, with its bound.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, NoReturn

import numpy as np

from membrane_client.codec import pack_array, preview, unpack_array
from membrane_client.errors import ProtocolError, UserError

__all__ = [
    "GRASP_KEYS",
    "INITIAL_SHAPES",
    "LOAD_KEYS",
    "MAX_DEPTH",
    "MAX_FORCE",
    "MAX_GRASPS",
    "MAX_LOADS",
    "MAX_PROBES",
    "MAX_RADIUS",
    "MAX_TOOLS",
    "PROBE_KEYS",
    "STEP_UNITS",
    "TOOL_KEYS",
    "TOOL_KINDS",
    "CloseReply",
    "Grasp",
    "GraspReading",
    "Initial",
    "LiveInputError",
    "LiveStepReply",
    "Load",
    "OpenReply",
    "Probe",
    "ProbeReading",
    "ResetReply",
    "Tool",
    "ToolReading",
    "grasps_from_wire",
    "loads_from_wire",
    "probes_from_wire",
    "tools_from_wire",
]

# Per step: the contact problem is solved exactly (by enumeration at worst), so counts are small.
MAX_LOADS = 64
MAX_PROBES = 8
MAX_GRASPS = 8
MAX_TOOLS = 4
# Magnitudes in problem units that a server of this version takes (describe's ``live`` says the
# served engine's own): far past any meaningful input, small enough that no sum of a step
# overflows float64 nor a frame float32.
MAX_FORCE = 1e6
MAX_DEPTH = 1e3
MAX_RADIUS = 10.0

# The items' maps, key by key in the order ``to_wire`` writes them.
LOAD_KEYS = ("at", "force", "radius")
PROBE_KEYS = ("at", "depth", "radius")
GRASP_KEYS = ("at", "height", "radius")
TOOL_KEYS = ("kind", "at", "depth", "radius")
# A tool's ``kind``: a sphere (a ball tip) or a flat-ended cylinder (a punch), its axis along the
# displacement axis.
TOOL_KINDS = ("sphere", "cylinder")
# An open's ``initial`` map: shapes on the lattice (also the names of the open reply's residuals).
INITIAL_SHAPES = ("displacement", "velocity")
# describe's ``live.units``: what a step's numbers are measured in.
STEP_UNITS = {
    "at": "problem units (lattice coordinates)",
    "force": "total force, problem units; a load's > 0 pushes along +axis",
    "depth": "below the rest surface, problem units (a probe presses along -axis)",
    "k": "steps taken; t = k * dt",
}

_LOAD_SET = frozenset(LOAD_KEYS)
_PROBE_SET = frozenset(PROBE_KEYS)
_GRASP_SET = frozenset(GRASP_KEYS)
_TOOL_SET = frozenset(TOOL_KEYS)
_KIND_NAMES = " or ".join(repr(kind) for kind in TOOL_KINDS)


class LiveInputError(UserError):
    """A load, probe or initial shape that breaks the live schema, or a bound on it: one line,
    a peer's values quoted short. The server answers it with ``bad_request``."""


class Load(NamedTuple):
    """A Gaussian pressure of total ``force`` (> 0 pushes along +axis) centred ``at``."""

    at: tuple[float, ...]  # (x,) on a string, (x, y) on a membrane, problem units
    force: float
    radius: float  # > 0 on a membrane; 0 is a point force on a string

    def to_wire(self) -> dict[str, Any]:
        """The load's map in a step's ``loads``."""
        return {"at": [float(a) for a in self.at], "force": self.force, "radius": self.radius}

    @classmethod
    def from_wire(cls, item: Any, dims: int, what: str = "load") -> Load:
        """A load from its map (``what`` names it in messages); raises ``LiveInputError``."""
        if type(item) is not dict or item.keys() != _LOAD_SET:
            _refuse_map(item, LOAD_KEYS, what)
        at, force, radius = item["at"], item["force"], item["radius"]
        return cls(  # checked's body, inlined: the server reads items on every step
            point(at, dims, what), number(force, what, "force"), number(radius, what, "radius")
        )

    @classmethod
    def checked(cls, at: Any, force: Any, radius: Any, dims: int, what: str = "load") -> Load:
        """A load from untrusted values: floats, ``at`` of ``dims`` of them, all finite."""
        return cls(
            point(at, dims, what), number(force, what, "force"), number(radius, what, "radius")
        )


class Probe(NamedTuple):
    """A rigid tip whose face is ``depth`` below the rest surface (< 0: above it), pressing
    along -axis."""

    at: tuple[float, ...]
    depth: float
    radius: float

    def to_wire(self) -> dict[str, Any]:
        """The probe's map in a step's ``probes``."""
        return {"at": [float(a) for a in self.at], "depth": self.depth, "radius": self.radius}

    @classmethod
    def from_wire(cls, item: Any, dims: int, what: str = "probe") -> Probe:
        """A probe from its map (``what`` names it in messages); raises ``LiveInputError``."""
        if type(item) is not dict or item.keys() != _PROBE_SET:
            _refuse_map(item, PROBE_KEYS, what)
        at, depth, radius = item["at"], item["depth"], item["radius"]
        return cls(  # checked's body, inlined: a 1 kHz haptic step reads one
            point(at, dims, what), number(depth, what, "depth"), number(radius, what, "radius")
        )

    @classmethod
    def checked(cls, at: Any, depth: Any, radius: Any, dims: int, what: str = "probe") -> Probe:
        """A probe from untrusted values: floats, ``at`` of ``dims`` of them, all finite."""
        return cls(
            point(at, dims, what), number(depth, what, "depth"), number(radius, what, "radius")
        )


class Grasp(NamedTuple):
    """A hold keeping the tissue's footprint-weighted displacement at ``height`` (signed, along
    +axis: > 0 lifts) by a force of either sign."""

    at: tuple[float, ...]
    height: float
    radius: float

    def to_wire(self) -> dict[str, Any]:
        """The grasp's map in a step's ``grasps``."""
        return {"at": [float(a) for a in self.at], "height": self.height, "radius": self.radius}

    @classmethod
    def from_wire(cls, item: Any, dims: int, what: str = "grasp") -> Grasp:
        """A grasp from its map (``what`` names it in messages); raises ``LiveInputError``."""
        if type(item) is not dict or item.keys() != _GRASP_SET:
            _refuse_map(item, GRASP_KEYS, what)
        at, height, radius = item["at"], item["height"], item["radius"]
        return cls(
            point(at, dims, what), number(height, what, "height"), number(radius, what, "radius")
        )


class Tool(NamedTuple):
    """A rigid tool of ``kind`` (``TOOL_KINDS``) and ``radius`` whose lowest point is ``depth``
    below the rest surface over ``at`` (< 0: above it), pressing along -axis."""

    kind: str  # "sphere" or "cylinder"
    at: tuple[float, ...]
    depth: float
    radius: float  # > 0: the sphere's or the cylinder's radius

    def to_wire(self) -> dict[str, Any]:
        """The tool's map in a step's ``tools``."""
        at = [float(a) for a in self.at]
        return {"kind": self.kind, "at": at, "depth": self.depth, "radius": self.radius}

    @classmethod
    def from_wire(cls, item: Any, dims: int, what: str = "tool") -> Tool:
        """A tool from its map (``what`` names it in messages); raises ``LiveInputError``."""
        if type(item) is not dict or item.keys() != _TOOL_SET:
            _refuse_map(item, TOOL_KEYS, what)
        kind, at, depth, radius = item["kind"], item["at"], item["depth"], item["radius"]
        return cls(
            _tool_kind(kind, what),
            point(at, dims, what),
            number(depth, what, "depth"),
            number(radius, what, "radius"),
        )


def loads_from_wire(items: Sequence[Any], dims: int) -> tuple[Load, ...]:
    """A step's ``loads`` (a list the envelope bounded), each named by its index in messages."""
    names = _LOAD_NAMES if len(items) <= MAX_LOADS else _names("load", len(items))
    return tuple([Load.from_wire(item, dims, names[i]) for i, item in enumerate(items)])


def probes_from_wire(items: Sequence[Any], dims: int) -> tuple[Probe, ...]:
    """A step's ``probes`` (a list the envelope bounded), each named by its index in messages."""
    names = _PROBE_NAMES if len(items) <= MAX_PROBES else _names("probe", len(items))
    return tuple([Probe.from_wire(item, dims, names[i]) for i, item in enumerate(items)])


def grasps_from_wire(items: Sequence[Any], dims: int) -> tuple[Grasp, ...]:
    """A step's ``grasps`` (a list the envelope bounded), each named by its index."""
    return tuple([Grasp.from_wire(item, dims, f"grasp {i}") for i, item in enumerate(items)])


def tools_from_wire(items: Sequence[Any], dims: int) -> tuple[Tool, ...]:
    """A step's ``tools`` (a list the envelope bounded), each named by its index."""
    return tuple([Tool.from_wire(item, dims, f"tool {i}") for i, item in enumerate(items)])


def _names(what: str, count: int) -> tuple[str, ...]:
    return tuple(f"{what} {index}" for index in range(count))


# Made once: a 1 kHz haptic step should not format a name it will not print.
_LOAD_NAMES, _PROBE_NAMES = _names("load", MAX_LOADS), _names("probe", MAX_PROBES)


class ProbeReading(NamedTuple):
    """What a probe felt at the end of a step (NaN displacement and gap when ``outside``)."""

    force: float  # contact force >= 0 (the tissue is pushed along -axis, the tool along +axis)
    displacement: float  # the footprint-weighted displacement under the tip
    gap: float  # >= 0, 0 in contact
    in_contact: bool
    outside: bool  # the tip's centre is outside the domain: nothing touched
    # The step's one-step compliance under the tip (displacement per unit contact force, held
    # over the step; NaN from a server that does not send it or when ``outside``): without the
    # contact the tip would have seen ``displacement + compliance * force``, so a force for any
    # other depth d of the same step is max(0, (that + d) / compliance) (``haptics``).
    compliance: float = math.nan
    # The static compliance under the tip (1 / the tissue's stiffness there, settled).
    static_compliance: float = math.nan
    # With ``lookahead``: the tissue's displacement under the tip at the end of the next step
    # if that step took no contact force (its loads those of this step), so that the next step's
    # force at depth d is max(0, (next_free + d) / compliance) (``haptics``); else NaN.
    next_free: float = math.nan

    def to_wire(self) -> dict[str, Any]:
        """The reading's map in a step or read reply's ``probes`` (``next_free`` only when it
        was asked for)."""
        wire = {
            "force": self.force,
            "displacement": self.displacement,
            "gap": self.gap,
            "in_contact": self.in_contact,
            "outside": self.outside,
            "compliance": self.compliance,
            "static_compliance": self.static_compliance,
        }
        if not math.isnan(self.next_free):
            wire["next_free"] = self.next_free
        return wire

    @classmethod
    def from_wire(cls, item: Any) -> ProbeReading:
        """A reading from its map (keys it does not know are a newer server's, and ignored);
        raises ProtocolError when one is missing or of the wrong type."""
        if type(item) is not dict:
            raise ProtocolError(f"a probe reading must be a map, got {preview(item)}")
        try:
            force, displacement, gap = item["force"], item["displacement"], item["gap"]
            in_contact, outside = item["in_contact"], item["outside"]
            if type(in_contact) is not bool or type(outside) is not bool:
                raise TypeError("in_contact and outside must be booleans")
            numbers = _reply_number(force), _reply_number(displacement), _reply_number(gap)
            extra = [_reply_number(item.get(key, math.nan)) for key in _READING_EXTRAS]
        except (KeyError, TypeError) as exc:
            raise ProtocolError(f"malformed probe reading: {exc!r}") from None
        return cls(*numbers, in_contact, outside, *extra)


# A probe reading's fields added within v1, NaN from a server that does not send them.
_READING_EXTRAS = ("compliance", "static_compliance", "next_free")


class GraspReading(NamedTuple):
    """What a grasp needed at the end of a step (NaN displacement when ``outside``)."""

    force: float  # applied to the tissue along +axis (> 0 lifts; the hand feels -force)
    displacement: float  # the footprint-weighted displacement: the grasp's height
    outside: bool  # the centre is outside the domain: nothing held

    def to_wire(self) -> dict[str, Any]:
        """The reading's map in a step or read reply's ``grasps``."""
        return {"force": self.force, "displacement": self.displacement, "outside": self.outside}

    @classmethod
    def from_wire(cls, item: Any) -> GraspReading:
        """A reading from its map (unknown keys ignored); raises ProtocolError."""
        if type(item) is not dict:
            raise ProtocolError(f"a grasp reading must be a map, got {preview(item)}")
        try:
            outside = item["outside"]
            if type(outside) is not bool:
                raise TypeError("outside must be a boolean")
            force, displacement = _reply_number(item["force"]), _reply_number(item["displacement"])
        except (KeyError, TypeError) as exc:
            raise ProtocolError(f"malformed grasp reading: {exc!r}") from None
        return cls(force, displacement, outside)


class ToolReading(NamedTuple):
    """What a rigid tool measured at the end of a step (NaN gap and penetration when no lattice
    point lies under it)."""

    force: float  # total contact force >= 0 (pushes the tissue along -axis, the tool along +axis)
    centre: tuple[float, ...]  # where it acts: force-weighted (the tool's centre when 0)
    contacts: int  # lattice points in contact
    points: int  # lattice points under the tool
    gap: float  # the least distance from the tool's surface to the tissue (0 in contact)
    penetration: float  # the most tissue above the tool's surface (0 up to rounding)

    def to_wire(self) -> dict[str, Any]:
        """The reading's map in a step or read reply's ``tools``."""
        return {
            "force": self.force,
            "centre": [float(c) for c in self.centre],
            "contacts": self.contacts,
            "points": self.points,
            "gap": self.gap,
            "penetration": self.penetration,
        }

    @classmethod
    def from_wire(cls, item: Any) -> ToolReading:
        """A reading from its map (unknown keys ignored); raises ProtocolError."""
        if type(item) is not dict:
            raise ProtocolError(f"a tool reading must be a map, got {preview(item)}")
        try:
            centre = item["centre"]
            if type(centre) is not list:
                raise TypeError(f"centre must be a list, got {preview(centre)}")
            return cls(
                _reply_number(item["force"]),
                tuple([_reply_number(c) for c in centre]),
                _reply_count(item["contacts"]),
                _reply_count(item["points"]),
                _reply_number(item["gap"]),
                _reply_number(item["penetration"]),
            )
        except (KeyError, TypeError) as exc:
            raise ProtocolError(f"malformed tool reading: {exc!r}") from None


@dataclass(frozen=True, eq=False)
class Initial:
    """An open's ``initial``: shapes on the lattice, flattened (None: at rest)."""

    displacement: np.ndarray | None = None
    velocity: np.ndarray | None = None

    def to_wire(self) -> dict[str, Any] | None:
        """The ``initial`` map, float32 shapes (None when neither is given: open from rest)."""
        shapes = {"displacement": self.displacement, "velocity": self.velocity}
        packed = {k: pack_array(np.asarray(v), "<f4") for k, v in shapes.items() if v is not None}
        return packed or None

    @classmethod
    def from_wire(cls, initial: Mapping[str, Any] | None) -> Initial:
        """The shapes of a request's ``initial`` (its keys the envelope checked); raises
        ``LiveInputError`` naming the shape whose array is malformed."""
        shapes: dict[str, np.ndarray] = {}
        for name, packed in (initial or {}).items():
            try:
                shapes[name] = unpack_array(packed).reshape(-1)
            except ProtocolError as exc:
                raise LiveInputError(f"initial {name}: {exc}") from None
        return cls(shapes.get("displacement"), shapes.get("velocity"))


@dataclass(frozen=True)
class OpenReply:
    """``open``'s reply: the session at step 0, and how well the modes carry its shapes."""

    session: str
    revision: str  # of the scene (and engine) the session opened on
    displacement_residual: float = 0.0  # relative least-squares residual on the modes
    velocity_residual: float = 0.0
    k: int = 0
    t: float = 0.0

    @property
    def residuals(self) -> dict[str, float]:
        """The residuals by shape name."""
        return {"displacement": self.displacement_residual, "velocity": self.velocity_residual}

    def to_reply_fields(self) -> dict[str, Any]:
        """The reply's fields (the server writes them)."""
        return {
            "session": self.session,
            "k": self.k,
            "t": self.t,
            "revision": self.revision,
            "residuals": self.residuals,
        }

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> OpenReply:
        """Read the reply; raises ProtocolError when a field is missing or malformed."""
        try:
            residuals = reply.get("residuals", {})
            return cls(
                session=str(reply["session"]),
                revision=str(reply.get("revision", "")),
                displacement_residual=_reply_number(residuals.get("displacement", 0.0)),
                velocity_residual=_reply_number(residuals.get("velocity", 0.0)),
                k=_reply_count(reply["k"]),
                t=_reply_number(reply["t"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ProtocolError(f"malformed open reply: {exc!r}") from None


@dataclass(frozen=True, eq=False)
class LiveStepReply:
    """``step``'s and ``read``'s reply: the state after step ``k`` and each probe's reading."""

    session: str
    k: int  # steps taken
    t: float  # k dt
    revision: str
    probes: tuple[ProbeReading, ...]  # one per probe of the step, in order
    z: np.ndarray | None = None  # the frame, shaped like the lattice; None: a step without one
    token: str | None = None  # read: the token of the step the state follows
    dtype: str = "<f4"  # the frame's element type on the wire (the request's ``dtype``)
    grasps: tuple[GraspReading, ...] = ()  # one per grasp of the step; the key is left out if none
    tools: tuple[ToolReading, ...] = ()  # one per tool of the step; the key is left out if none

    def to_reply_fields(self) -> dict[str, Any]:
        """The reply's fields, ``z`` as ``dtype`` (the server writes them)."""
        fields: dict[str, Any] = {
            "session": self.session,
            "k": self.k,
            "t": self.t,
            "revision": self.revision,
            "probes": [reading.to_wire() for reading in self.probes],
        }
        if self.z is not None:
            fields["z"] = pack_array(self.z, self.dtype)
        if self.token is not None:
            fields["token"] = self.token
        if self.grasps:
            fields["grasps"] = [reading.to_wire() for reading in self.grasps]
        if self.tools:
            fields["tools"] = [reading.to_wire() for reading in self.tools]
        return fields

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> LiveStepReply:
        """Read the reply; raises ProtocolError when a field is missing or malformed."""
        try:
            readings = reply["probes"]
            if type(readings) is not list:
                raise TypeError(f"probes must be a list, got {preview(readings)}")
            token = reply.get("token")
            held = reply.get("grasps", [])
            if type(held) is not list:
                raise TypeError(f"grasps must be a list, got {preview(held)}")
            pressed = reply.get("tools", [])
            if type(pressed) is not list:
                raise TypeError(f"tools must be a list, got {preview(pressed)}")
            return cls(
                session=str(reply.get("session", "")),
                k=_reply_count(reply["k"]),
                t=_reply_number(reply["t"]),
                revision=str(reply.get("revision", "")),
                probes=tuple(ProbeReading.from_wire(item) for item in readings),
                z=unpack_array(reply["z"]) if "z" in reply else None,
                token=None if token is None else str(token),
                grasps=tuple(GraspReading.from_wire(item) for item in held),
                tools=tuple(ToolReading.from_wire(item) for item in pressed),
            )
        except (KeyError, TypeError, ValueError, ProtocolError) as exc:
            raise ProtocolError(f"malformed live reply: {exc!r}") from None


@dataclass(frozen=True)
class ResetReply:
    """``reset``'s reply: the session back at step 0."""

    session: str
    k: int = 0
    t: float = 0.0

    def to_reply_fields(self) -> dict[str, Any]:
        """The reply's fields (the server writes them)."""
        return {"session": self.session, "k": self.k, "t": self.t}

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> ResetReply:
        """Read the reply; raises ProtocolError when a field is missing or malformed."""
        try:
            k, t = _reply_count(reply["k"]), _reply_number(reply.get("t", 0.0))
            return cls(str(reply.get("session", "")), k, t)
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"malformed reset reply: {exc!r}") from None


@dataclass(frozen=True)
class CloseReply:
    """``close``'s reply: whether the session was open (closing twice is harmless)."""

    session: str
    closed: bool

    def to_reply_fields(self) -> dict[str, Any]:
        """The reply's fields (the server writes them)."""
        return {"session": self.session, "closed": self.closed}

    @classmethod
    def from_reply(cls, reply: Mapping[str, Any]) -> CloseReply:
        """Read the reply; raises ProtocolError when a field is missing or malformed."""
        closed = reply.get("closed")
        if type(closed) is not bool:
            raise ProtocolError(f"malformed close reply: closed is {preview(closed)}")
        return cls(str(reply.get("session", "")), closed)


def point(at: Any, dims: int, what: str) -> tuple[float, ...]:
    """``at`` as ``dims`` finite floats: a list or tuple of exactly that many numbers (on a
    string a bare number too, as servers have always taken)."""
    kind = type(at)
    if (kind is list or kind is tuple) and len(at) == dims:
        for x in at:
            if type(x) is not float or not math.isfinite(x):
                return tuple([number(x, what, "at") for x in at])
        return tuple(at)
    if dims == 1 and (kind is float or kind is int):
        return (number(at, what, "at"),)
    count = len(at) if kind is list or kind is tuple else -1
    got = f"{count} value{'' if count == 1 else 's'}" if count >= 0 else preview(at)
    plural = "s" if dims > 1 else ""
    _refuse(f"{what} at must be {dims} number{plural}, got {got}")


def _tool_kind(kind: Any, what: str) -> str:
    """``kind`` as one of ``TOOL_KINDS``: a string equal to one (so of bounded length), never
    a bool, a number or a container; messages name the kinds and quote it short."""
    if type(kind) is str and kind in TOOL_KINDS:
        return kind
    got = preview(kind) if type(kind) is str else _kind(kind)
    _refuse(f"{what} kind must be {_KIND_NAMES}, got {got}")


def number(value: Any, what: str, field: str) -> float:
    """A finite float from an int or a float (never a bool, a string or a container); messages
    name it ``what field``."""
    if type(value) is float:
        if math.isfinite(value):
            return value
        _refuse(f"{what} {field} must be finite, got {preview(value)}")
    if type(value) is not int:
        _refuse(f"{what} {field} must be a number, got {_kind(value)}")
    try:
        return float(value)
    except OverflowError:
        _refuse(f"{what} {field} must be a finite number, got a huge integer")


def _refuse_map(item: Any, keys: tuple[str, ...], what: str) -> NoReturn:
    names = sorted(keys)
    if not isinstance(item, dict):
        _refuse(f"{what} must be a map with keys {names}, got {_kind(item)}")
    missing = sorted(set(keys) - item.keys())
    extra = len(item.keys() - set(keys))
    _refuse(f"{what} needs exactly the keys {names} (missing {missing}, {extra} extra)")


def _refuse(message: str) -> NoReturn:
    raise LiveInputError(message)


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return f"a bool ({value})"
    if value is None:
        return "null"
    if isinstance(value, str):
        return f"a string {preview(value)}"
    return preview(value) if isinstance(value, list | tuple | dict) else type(value).__name__


def _reply_number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"expected a number, got {preview(value)}")
    return float(value)


def _reply_count(value: Any) -> int:
    if type(value) is not int:
        raise TypeError(f"expected an int, got {preview(value)}")
    return value
