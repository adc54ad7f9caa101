"""World <-> scene coordinates: the placement of ``describe`` (docs/PROTOCOL.md) both ways.

A lattice point ``p`` (d = 1 or 2 scene coordinates) rests at ``origin + size * p`` on the world
axes other than ``axis`` (in x, y, z order), and a displacement ``z`` moves it by ``scale * z``
along ``axis``. ``SceneInfo.positions`` goes forward; ``to_scene`` here goes back, so that a
simulator's tool tip (a world point) becomes a probe's ``at`` and depth without each client
re-deriving the placement. Kept apart from ``frame.py``: pure functions of numbers, testable
without a reply.
"""

from __future__ import annotations

import logging
import threading
import warnings
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from membrane_client.errors import UserError

__all__ = ["Extent", "OnceGate", "lateral_axes", "to_scene", "warn_outside"]

log = logging.getLogger(__name__)

# Points on the extent's boundary come back from the world a few ulps off it; a tolerance this
# much smaller than the extent keeps them inside without letting a real miss through.
_RELATIVE_SLACK = 1e-9


class Extent(NamedTuple):
    """A scene's axis-aligned bounding box in scene coordinates, (d,) arrays, lower <= upper."""

    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def of_points(cls, points: np.ndarray) -> Extent:
        """The lattice's own box: what a reply without ``extent`` spans (dimensionless scenes:
        [0, 1] per axis)."""
        return cls.of_bounds(points.min(axis=0), points.max(axis=0))

    @classmethod
    def from_wire(cls, item: Any, dims: int) -> Extent:
        """``describe``'s ``{"lower": [..], "upper": [..]}``; raises ValueError when it is not
        two lists of ``dims`` finite numbers with lower <= upper (the reply's reader turns that
        into a ProtocolError)."""
        if not isinstance(item, dict) or set(item) != {"lower", "upper"}:
            raise ValueError(f"extent must be a map of 'lower' and 'upper', got {item!r:.64}")
        lower, upper = (_coordinates(item[key], dims, key) for key in ("lower", "upper"))
        if not np.all(lower <= upper):
            raise ValueError(f"extent's lower {lower.tolist()} exceeds upper {upper.tolist()}")
        return cls.of_bounds(lower, upper)

    def to_wire(self) -> dict[str, list[float]]:
        """The map ``from_wire`` reads."""
        return {"lower": [float(v) for v in self.lower], "upper": [float(v) for v in self.upper]}

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bools: which of the (n, d) points lie in the box (boundary included, to within
        a billionth of the box's size)."""
        span = np.maximum(self.upper - self.lower, np.maximum(abs(self.lower), abs(self.upper)))
        slack = _RELATIVE_SLACK * span
        inside = (points >= self.lower - slack) & (points <= self.upper + slack)
        result: np.ndarray = np.all(inside, axis=1)
        return result

    @classmethod
    def of_bounds(cls, lower: Any, upper: Any) -> Extent:
        """The box from its corners, as read-only float64 arrays (unchecked: ``from_wire``
        checks a peer's)."""
        lower, upper = np.array(lower, dtype=np.float64), np.array(upper, dtype=np.float64)
        lower.setflags(write=False)
        upper.setflags(write=False)
        return cls(lower, upper)


class OnceGate:
    """True the first time it is passed, False ever after, also across threads: a simulator
    loop polling 1,000 times a second must not log 1,000 lines a second."""

    def __init__(self) -> None:
        self._lock = threading.Lock()

    def first(self) -> bool:
        """Whether this is the first pass (the lock is taken once and never released)."""
        return self._lock.acquire(blocking=False)

    def __reduce__(self) -> tuple[type[OnceGate], tuple[()]]:
        # A lock does not pickle; a copied description (another process's) warns afresh.
        return (OnceGate, ())


def lateral_axes(axis: int, dims: int) -> list[int]:
    """The world axes the scene's ``dims`` coordinates lie on: the axes other than ``axis``, in
    x, y, z order (as the placement lays them)."""
    return [i for i in range(3) if i != axis][:dims]


def to_scene(
    world: np.ndarray | Sequence[float] | Sequence[Sequence[float]],
    origin: np.ndarray,
    size: float,
    scale: float,
    axis: int,
    dims: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(scene points (n, d), heights (n,)) of (3,) or (n, 3) world points.

    The height is ``(world[axis] - origin[axis]) / scale``: the displacement a sphere at that
    world height has, so a probe tip there is ``-height`` deep when below the rest plane. On a
    1-D scene the world coordinate across the line is dropped: a line has no width.
    """
    if size == 0.0 or scale == 0.0:
        raise UserError(f"placement size ({size}) and scale ({scale}) must be non-zero")
    points = np.asarray(world, dtype=np.float64)
    if points.ndim == 1:
        points = points[np.newaxis, :]
    if points.ndim != 2 or points.shape[1] != 3:
        raise UserError(f"world points must be (3,) or (n, 3), got {np.shape(world)}")
    lateral = lateral_axes(axis, dims)
    scene = (points[:, lateral] - origin[lateral]) / size
    heights = (points[:, axis] - origin[axis]) / scale
    return scene, heights


def warn_outside(scene_name: str, point: np.ndarray, extent: Extent) -> None:
    """Say, in the log and as a UserWarning, that a point is outside the scene: the server will
    clamp, refuse or extrapolate it, and a client usually has a placement wrong."""
    message = (
        f"scene {scene_name}: point {point.tolist()} is outside the scene's extent "
        f"{extent.lower.tolist()} .. {extent.upper.tolist()} (said once per scene description)"
    )
    log.warning("%s", message)
    warnings.warn(message, UserWarning, stacklevel=3)


def _coordinates(values: Any, dims: int, what: str) -> np.ndarray:
    if not isinstance(values, list | tuple) or len(values) != dims:
        raise ValueError(f"extent's {what} must list {dims} numbers, got {values!r:.64}")
    if any(isinstance(v, bool) or not isinstance(v, int | float) for v in values):
        raise ValueError(f"extent's {what} must hold numbers, got {values!r:.64}")
    array = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"extent's {what} must be finite, got {values!r:.64}")
    return array
