"""A live scene's per-step bounds, read from its ``describe`` reply, to check probes and loads
before they are sent.

The server checks every step itself; checking first lets a relay (the browser bridge, a robot's
controller) refuse bad input from its own caller with a short message and keep its session,
instead of sending it and losing a round trip or the session to a ``bad_request``.

```python
limits = LiveLimits.from_live(info.live, dims=info.points.shape[1])
probe = limits.check_probe(at, depth, radius)  # a Probe, or raises InvalidInput
```

Bounds missing from ``live`` (an older server) fall back to the defaults below, the same as the
server's own. Messages quote at most 64 characters of any value (``protocol.preview``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from membrane_client.errors import UserError
from membrane_client.protocol import MAX_LOADS, MAX_PROBES, preview
from membrane_client.session import Load, Probe

__all__ = [
    "DEFAULT_MAX_DEPTH",
    "DEFAULT_MAX_FORCE",
    "DEFAULT_MAX_RADIUS",
    "InvalidInput",
    "LiveLimits",
]

# The server's bounds (membrane_models.live.inputs) for a server whose describe omits them.
DEFAULT_MAX_FORCE = 1e6
DEFAULT_MAX_DEPTH = 1e3
DEFAULT_MAX_RADIUS = 10.0


class InvalidInput(UserError):
    """A probe or load outside the scene's bounds (a one-line message, values quoted short)."""


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
        )

    def check_probe(
        self, at: Any, depth: Any, radius: Any, *, max_depth: float | None = None
    ) -> Probe:
        """A ``Probe`` from untrusted values (JSON numbers: bools and strings are refused).

        ``max_depth`` tightens the depth bound (a caller's own, e.g. a slider's maximum).
        Raises ``InvalidInput`` naming the first field that is wrong.
        """
        point = self.check_point(at, "probe")
        limit = self.max_depth if max_depth is None else min(self.max_depth, max_depth)
        value = _number(depth, "probe depth")
        if not 0.0 <= value <= limit:
            raise InvalidInput(f"probe depth must be in [0, {limit:.6g}], got {value:.6g}")
        return Probe(point, value, self._radius(radius, "probe"))

    def check_load(self, at: Any, force: Any, radius: Any) -> Load:
        """A ``Load`` from untrusted values; its centre must lie in the unit domain."""
        point = self.check_point(at, "load")
        if not all(0.0 <= x <= 1.0 for x in point):
            raise InvalidInput("load at must lie in the unit domain [0, 1]")
        value = _number(force, "load force")
        if abs(value) > self.max_force:
            limit = f"{self.max_force:.6g}"
            raise InvalidInput(f"|load force| must be at most {limit}, got {value:.6g}")
        return Load(point, value, self._radius(radius, "load"))

    def check_count(self, probes: int = 0, loads: int = 0) -> None:
        """Refuse a step with more probes or loads than the scene takes."""
        if probes > self.max_probes:
            raise InvalidInput(f"at most {self.max_probes} probes per step, got {probes}")
        if loads > self.max_loads:
            raise InvalidInput(f"at most {self.max_loads} loads per step, got {loads}")

    def check_point(self, at: Any, what: str) -> tuple[float, ...]:
        """``dims`` finite numbers (a list or tuple of exactly that length)."""
        if type(at) not in (list, tuple) or len(at) != self.dims:
            count = len(at) if type(at) in (list, tuple) else -1
            got = f"{count} value{'' if count == 1 else 's'}" if count >= 0 else preview(at)
            plural = "s" if self.dims > 1 else ""
            raise InvalidInput(f"{what} at must be {self.dims} number{plural}, got {got}")
        return tuple(_number(x, f"{what} at") for x in at)

    def _radius(self, radius: Any, what: str) -> float:
        value = _number(radius, f"{what} radius")
        if not self.min_radius <= value <= self.max_radius:
            raise InvalidInput(
                f"{what} radius must be in [{self.min_radius:.6g}, {self.max_radius:.6g}], "
                f"got {value:.6g}"
            )
        if value == 0.0 and self.dims == 2:
            raise InvalidInput(f"{what} radius must be > 0 on a membrane (a point is singular)")
        return value


def _number(value: Any, what: str) -> float:
    """A finite float from an int or float (never a bool, a string or a container)."""
    if type(value) is float:
        number = value
    elif type(value) is int:
        try:
            number = float(value)
        except OverflowError:
            raise InvalidInput(f"{what} must be a finite number, got a huge integer") from None
    else:
        raise InvalidInput(f"{what} must be a number, got {_kind(value)}")
    if not math.isfinite(number):
        raise InvalidInput(f"{what} must be finite, got {preview(number)}")
    return number


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return f"a bool ({value})"
    if value is None:
        return "null"
    if isinstance(value, str):
        return f"a string {preview(value)}"
    return preview(value) if isinstance(value, list | tuple | dict) else type(value).__name__


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
