"""A live scene's per-step bounds, read from its ``describe`` reply, to check probes and loads
before they are sent.

The server checks every step itself; checking first lets a relay (the browser bridge, a robot's
controller) refuse bad input from its own caller with a short message and keep its session,
instead of sending it and losing a round trip or the session to a ``bad_request``.

```python
limits = LiveLimits.from_live(info.live, dims=info.points.shape[1])
probe = limits.check_probe(at, depth, radius)  # a Probe, or raises InvalidInput
```

The items' form is the live schema's (``live_schema.Probe.checked``, ``Load.checked``: the same
checks the server makes of their wire maps); this adds the scene's bounds. Bounds missing from
``live`` (an older server) fall back to the schema's. Messages quote at most 64 characters of any
value (``codec.preview``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from membrane_client.codec import preview
from membrane_client.live_schema import (
    MAX_DEPTH,
    MAX_FORCE,
    MAX_LOADS,
    MAX_PROBES,
    MAX_RADIUS,
    LiveInputError,
    Load,
    Probe,
    point,
)

__all__ = [
    "DEFAULT_MAX_DEPTH",
    "DEFAULT_MAX_FORCE",
    "DEFAULT_MAX_RADIUS",
    "InvalidInput",
    "LiveLimits",
]

# The schema's bounds, for a server whose describe omits them.
DEFAULT_MAX_FORCE = MAX_FORCE
DEFAULT_MAX_DEPTH = MAX_DEPTH
DEFAULT_MAX_RADIUS = MAX_RADIUS

# A probe or load that breaks the schema or the scene's bounds: the schema's own error.
InvalidInput = LiveInputError


@dataclass(frozen=True)
class LiveLimits:
    """What one step of a live scene accepts: counts and magnitudes, in problem units."""

    dims: int  # coordinates per point: 1 on a string, 2 on a membrane
    max_probes: int = MAX_PROBES
    max_loads: int = MAX_LOADS
    min_radius: float = 0.0  # the smallest footprint the engine carries (0: a point)
    max_radius: float = DEFAULT_MAX_RADIUS
    max_depth: float = DEFAULT_MAX_DEPTH
    max_force: float = DEFAULT_MAX_FORCE
    # A plate's tables may carry point forces (``radii`` holds 0): a point is finite there.
    point_forces: bool = False

    @classmethod
    def from_live(cls, live: Mapping[str, Any], dims: int) -> LiveLimits:
        """From a ``SceneInfo.live`` map: the server's bounds, or the defaults for keys that are
        missing or unusable (not finite numbers >= 0)."""
        if dims not in (1, 2):
            raise InvalidInput(f"a live scene has 1 or 2 dimensions, got {preview(dims)}")
        defaults = cls(dims)
        return cls(
            dims=dims,
            max_probes=_count(live.get("max_probes"), defaults.max_probes),
            max_loads=_count(live.get("max_loads"), defaults.max_loads),
            min_radius=_bound(live.get("min_radius"), defaults.min_radius),
            max_radius=_bound(live.get("max_radius"), defaults.max_radius),
            max_depth=_bound(live.get("max_depth"), defaults.max_depth),
            max_force=_bound(live.get("max_force"), defaults.max_force),
            point_forces=_has_zero(live.get("radii")),
        )

    def check_probe(
        self,
        at: Any,
        depth: Any,
        radius: Any,
        *,
        max_depth: float | None = None,
        min_depth: float | None = None,
    ) -> Probe:
        """A ``Probe`` from untrusted values (JSON numbers: bools and strings are refused).

        The depth is signed, within +-``max_depth`` (< 0: the tip above the rest surface);
        ``max_depth`` and ``min_depth`` tighten that (a caller's own, e.g. a slider's range).
        Raises ``InvalidInput`` naming the first field that is wrong.
        """
        probe = Probe.checked(at, depth, radius, self.dims)
        return self._probe(probe, max_depth, min_depth)

    def probe_from_wire(
        self, item: Any, *, max_depth: float | None = None, min_depth: float | None = None
    ) -> Probe:
        """``check_probe`` of a probe's wire map (``live_schema.Probe.from_wire``)."""
        return self._probe(Probe.from_wire(item, self.dims), max_depth, min_depth)

    def check_load(self, at: Any, force: Any, radius: Any) -> Load:
        """A ``Load`` from untrusted values; its centre must lie in the unit domain."""
        load = Load.checked(at, force, radius, self.dims)
        if not all(0.0 <= x <= 1.0 for x in load.at):
            raise InvalidInput("load at must lie in the unit domain [0, 1]")
        if abs(load.force) > self.max_force:
            limit = f"{self.max_force:.6g}"
            raise InvalidInput(f"|load force| must be at most {limit}, got {load.force:.6g}")
        self._radius(load.radius, "load")
        return load

    def check_count(self, probes: int = 0, loads: int = 0) -> None:
        """Refuse a step with more probes or loads than the scene takes."""
        if probes > self.max_probes:
            raise InvalidInput(f"at most {self.max_probes} probes per step, got {probes}")
        if loads > self.max_loads:
            raise InvalidInput(f"at most {self.max_loads} loads per step, got {loads}")

    def check_point(self, at: Any, what: str) -> tuple[float, ...]:
        """``dims`` finite numbers (the schema's ``at``)."""
        return point(at, self.dims, what)

    def _probe(self, probe: Probe, max_depth: float | None, min_depth: float | None) -> Probe:
        limit = self.max_depth if max_depth is None else min(self.max_depth, max_depth)
        lowest = -self.max_depth if min_depth is None else max(-self.max_depth, min_depth)
        if not lowest <= probe.depth <= limit:
            bounds = f"[{lowest:.6g}, {limit:.6g}]"
            raise InvalidInput(f"probe depth must be in {bounds}, got {probe.depth:.6g}")
        self._radius(probe.radius, "probe")
        return probe

    def _radius(self, value: float, what: str) -> None:
        if not self.min_radius <= value <= self.max_radius:
            raise InvalidInput(
                f"{what} radius must be in [{self.min_radius:.6g}, {self.max_radius:.6g}], "
                f"got {value:.6g}"
            )
        if value == 0.0 and self.dims == 2 and not self.point_forces:
            raise InvalidInput(f"{what} radius must be > 0 on a membrane (a point is singular)")


def _has_zero(radii: Any) -> bool:
    return type(radii) is list and any(type(r) in (int, float) and r == 0 for r in radii)


def _count(value: Any, default: int) -> int:
    return value if type(value) is int and value >= 0 else default


def _bound(value: Any, default: float) -> float:
    if type(value) not in (int, float):
        return default
    try:
        number = float(value)
    except OverflowError:
        return default
    return number if math.isfinite(number) and number >= 0.0 else default
