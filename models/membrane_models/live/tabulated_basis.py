"""A modal basis given as tables: mode shapes on the lattice, footprints and the static
correction from providers. How modes computed elsewhere (FEM) reach the stepping core.

The modes are mass-normalised (int rho phi_j phi_k = delta_jk), so ``scale`` is 1: a
footprint's modal force per unit force is s_k = <g, phi_k> (the footprint g normalised to a unit
total force) and the footprint-weighted displacement is s . q. Mode values on the lattice are a
table ``shapes`` (points x modes); what depends on where a load or probe acts comes from two
providers, so that a basis can tabulate them however it likes (an FEM basis interpolates
tables precomputed at build time, since a point probe of the mesh costs milliseconds):

- ``FootprintModel.modal_force(at, radius)``: s for a footprint centred at ``at``;
- ``StaticCorrection`` (optional): the compliance of the modes not stepped between two
  footprints, and the field on the lattice of a unit force on one.

The sine modes fed through this class (shapes 2^(d/2) prod sin(m pi x), footprints from the
sine spectra) step exactly as ``engine.ModalEngine`` does (tests/models/live/test_basis.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.cost import StepBudget, table_step_cost
from membrane_models.live.errors import InvalidEngineSettings, InvalidLoad, InvalidProbe
from membrane_models.live.interface import Load, Probe
from membrane_models.live.modes import ModeSet
from membrane_models.live.projection import checked_shape

__all__ = ["FootprintModel", "StaticCorrection", "TableFootprint", "TabulatedBasis", "frozen"]

FloatArray = NDArray[np.float64]
_Array = TypeVar("_Array", bound=NDArray[Any])
_CLAMPED = 1e-9  # a lattice point whose modes all move less than this share of the largest
_RECENT = 16  # footprints kept read (each a modes-long vector: 1.2 kB for 100 modes)
_Key = TypeVar("_Key")
_Value = TypeVar("_Value")


@dataclass(frozen=True)
class TableFootprint:
    """Where a load or probe acts and its modal force per unit force (read-only)."""

    at: tuple[float, ...]
    radius: float
    modal_force: FloatArray


class FootprintModel(Protocol):
    """Modal forces of footprints, wherever they are centred in the domain."""

    def contains(self, at: tuple[float, ...]) -> bool:
        """Whether ``at`` lies in the domain."""

    def refuses(self, radius: float) -> str | None:
        """Why a footprint of ``radius`` cannot be carried (None: it can)."""

    def modal_force(self, at: tuple[float, ...], radius: float) -> FloatArray:
        """s_k = <g, phi_k> for every mode, g the unit footprint of ``radius`` at ``at``."""


class StaticCorrection(Protocol):
    """The static compliance of the modes a basis does not step."""

    def compliance(self, a: TableFootprint, b: TableFootprint) -> float:
        """Displacement under ``b`` per unit force on ``a`` (symmetric)."""

    def field(self, footprint: TableFootprint) -> FloatArray:
        """The displacement on the lattice (flattened) of a unit force on ``footprint``."""


class TabulatedBasis:
    """Mass-normalised modes given as tables (``ModalBasis[TableFootprint]``).

    Args:
        lattice: points per axis of the frames.
        shapes: mode values at the lattice points, (points, modes), points x-major.
        omega: angular frequencies (modes,), > 0.
        kept: the modes stepped (default: all); the others are left to ``correction``.
        footprints: the footprints' modal forces.
        correction: the static correction of the modes not stepped (None: none).
        description: what ``describe`` says of the basis besides the correction.
        held_bytes: bytes the providers' tables hold (counted in ``memory_bytes``).

    Raises:
        InvalidEngineSettings: tables of inconsistent sizes or not finite.
    """

    def __init__(
        self,
        lattice: tuple[int, ...],
        shapes: ArrayLike,
        omega: ArrayLike,
        footprints: FootprintModel,
        *,
        kept: ArrayLike | None = None,
        correction: StaticCorrection | None = None,
        description: Mapping[str, object] | None = None,
        held_bytes: int = 0,
    ) -> None:
        table = np.array(shapes, dtype=np.float64)
        w = np.array(omega, dtype=np.float64).reshape(-1)
        if table.ndim != 2 or table.shape != (math.prod(lattice), w.size):
            raise InvalidEngineSettings(
                f"the mode table must be (lattice points, modes) = ({math.prod(lattice)}, "
                f"{w.size}), got {table.shape}"
            )
        if not (np.isfinite(table).all() and np.isfinite(w).all() and (w > 0).all()):
            raise InvalidEngineSettings("the mode table and frequencies must be finite, w > 0")
        mask = np.ones(w.size, dtype=bool) if kept is None else np.array(kept, dtype=bool)
        if mask.shape != w.shape:
            raise InvalidEngineSettings(f"kept must mark {w.size} modes, got {mask.size}")
        self._lattice = tuple(lattice)
        # a clamped node's interpolated mode values are rounding (1e-20 of the largest)
        largest = np.abs(table).max(axis=1, initial=0.0)
        self._movable = frozen(largest > _CLAMPED * largest.max(initial=0.0))
        self._shapes = frozen(table * mask)  # modes not stepped carry nothing here
        w.setflags(write=False)
        self._modes = ModeSet((w.size,), w, frozen(mask))
        self._all_kept = bool(mask.all())
        self._footprints = footprints
        self._correction = correction
        self._inverse = frozen(np.linalg.pinv(table[:, mask]))  # least squares, kept modes
        self._description = dict(description or {"basis": "tabulated"})
        self._held_bytes = int(held_bytes)
        self._coordinates = frozen(_grid(self._lattice, self._description))
        # footprints read recently, by (at, radius): reading one from the tables costs tens of
        # microseconds, and a step's items and the next step's often sit where they did
        self._recent: dict[tuple[tuple[float, ...], float], TableFootprint] = {}
        self._recent_own: dict[tuple[tuple[float, ...], float], float] = {}
        self._recent_cross: dict[tuple[tuple[float, ...], float, tuple[float, ...], float], float]
        self._recent_cross = {}

    @property
    def spatial_dims(self) -> int:
        return len(self._lattice)

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        return self._lattice

    @property
    def modes(self) -> ModeSet:
        return self._modes

    @property
    def scale(self) -> float:
        return 1.0

    @property
    def static_correction(self) -> bool:
        return self._correction is not None

    @property
    def memory_bytes(self) -> int:
        recent = _RECENT * 8 * self._modes.omega.size  # the recent footprints, at most
        return int(self._shapes.nbytes + self._inverse.nbytes) + self._held_bytes + recent

    @property
    def engine_bytes(self) -> int:
        return self.memory_bytes

    @property
    def lattice_coordinates(self) -> FloatArray:
        """The uniform lattice over the description's ``lower`` .. ``upper`` (the unit box
        without them)."""
        return self._coordinates

    @property
    def movable(self) -> NDArray[np.bool_]:
        """Lattice points some mode moves (not clamped, inside the domain)."""
        return self._movable

    @property
    def tool_force_radius(self) -> float | None:
        """The smallest footprint radius the tables carry (0: point forces, a plate's)."""
        radii = self._description.get("radii")
        if not isinstance(radii, list) or not radii:
            return None
        return float(min(radii))

    def contains(self, at: tuple[float, ...]) -> bool:
        return self._footprints.contains(at)

    def describe(self) -> dict[str, object]:
        return {**self._description, "static_correction": self.static_correction}

    def footprints(
        self,
        loads: Sequence[Load],
        probes: Sequence[Probe],
        budget: StepBudget,
        *,
        tool_points: bool = False,
    ) -> tuple[list[TableFootprint], list[TableFootprint | None]]:
        inside = [self.contains(pr.at) for pr in probes]
        budget.check(
            table_step_cost(len(loads), sum(inside), self._modes.omega.size, self._shapes.shape[0])
        )
        load_prints = [self._footprint(ld, "load", i) for i, ld in enumerate(loads)]
        probe_prints = [
            self._footprint(pr, "probe", i) if within else None
            for i, (pr, within) in enumerate(zip(probes, inside, strict=True))
        ]
        return load_prints, probe_prints

    def modal_force(self, footprint: TableFootprint) -> FloatArray:
        return footprint.modal_force

    def modal_factors(self, footprint: TableFootprint) -> None:
        """FEM modes' forces are no outer products: the step takes ``modal_force``."""
        return None

    def own(self, footprint: TableFootprint) -> float:
        key = (footprint.at, footprint.radius)
        own = self._recent_own.get(key)
        if own is None:
            own = self.cross(footprint, footprint)
            _remember(self._recent_own, key, own)
        return own

    def cross(self, a: TableFootprint, b: TableFootprint) -> float:
        if self._correction is None:
            return 0.0
        key = (a.at, a.radius, b.at, b.radius)
        value = self._recent_cross.get(key)
        if value is None:
            value = self._correction.compliance(a, b)
            _remember(self._recent_cross, key, value)
        return value

    def loads_residual(
        self, prints: Sequence[TableFootprint], forces: Sequence[float]
    ) -> Callable[[TableFootprint], float]:
        pairs = [(fp, f) for fp, f in zip(prints, forces, strict=True) if f != 0.0]
        if not pairs or self._correction is None:
            return lambda probe: 0.0
        return lambda probe: sum(f * self.cross(fp, probe) for fp, f in pairs)

    def frame(self, q: FloatArray, applied: Sequence[tuple[TableFootprint, float]]) -> FloatArray:
        values = np.asarray(self._shapes @ q)
        if self._correction is not None:
            for footprint, force in applied:
                if force != 0.0:
                    values = values + force * self._correction.field(footprint)
        return values

    def point_frame(
        self,
        points: NDArray[np.intp],
        q: FloatArray,
        applied: Sequence[tuple[TableFootprint, float]],
    ) -> FloatArray:
        values = np.asarray(self._shapes[points] @ q)
        if self._correction is not None:
            for footprint, force in applied:
                if force != 0.0:
                    values = values + force * self._correction.field(footprint)[points]
        return values

    def point_compliance(
        self, points: NDArray[np.intp], prints: Sequence[TableFootprint], gain: FloatArray
    ) -> FloatArray:
        forces = np.stack([fp.modal_force for fp in prints], axis=1)
        compliance = self._shapes[points] @ (gain[:, None] * forces)
        if self._correction is not None:
            for j, footprint in enumerate(prints):
                compliance[:, j] += self._correction.field(footprint)[points]
        return np.asarray(compliance)

    def project(self, shape: ArrayLike, what: str) -> tuple[FloatArray, float]:
        values = checked_shape(shape, self._lattice, what)
        q = np.zeros(self._modes.omega.size)
        q[self._modes.kept] = self._inverse @ values
        norm = float(np.linalg.norm(values))
        if norm == 0.0:
            return q, 0.0
        return q, float(np.linalg.norm(values - self._shapes @ q)) / norm

    def _footprint(self, item: Load | Probe, kind: str, index: int) -> TableFootprint:
        key = (item.at, item.radius)
        recent = self._recent.get(key)
        if recent is not None:  # a haptic step's load, probe and look-ahead share one footprint
            return recent
        reason = self._footprints.refuses(item.radius)
        if reason is not None:
            error = InvalidLoad if kind == "load" else InvalidProbe
            raise error(f"{kind} {index}: {reason}")
        s = np.array(self._footprints.modal_force(item.at, item.radius), dtype=np.float64)
        if not self._all_kept:
            s *= self._modes.kept
        s.setflags(write=False)
        footprint = TableFootprint(item.at, item.radius, s)
        _remember(self._recent, key, footprint)
        return footprint


def _remember(recent: dict[_Key, _Value], key: _Key, value: _Value) -> None:
    """Keep ``value`` among the last ``_RECENT`` (the oldest goes first: dicts keep order)."""
    if len(recent) >= _RECENT:
        del recent[next(iter(recent))]
    recent[key] = value


def _grid(lattice: tuple[int, ...], description: Mapping[str, object]) -> FloatArray:
    """The uniform lattice's points, (points, dims), x-major."""
    lower = np.asarray(cast(ArrayLike, description.get("lower", [0.0] * len(lattice))), float)
    upper = np.asarray(cast(ArrayLike, description.get("upper", [1.0] * len(lattice))), float)
    axes = [np.linspace(a, b, n) for a, b, n in zip(lower, upper, lattice, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lattice))


def frozen(array: _Array) -> _Array:
    """``array`` made read-only (tables are shared between sessions), returned for chaining."""
    array.setflags(write=False)
    return array
