"""The sine modes of the clamped unit string and square, as a basis the stepping core steps.

Modes prod sin(m pi x) with w = c pi |m| (``modes``), their Gaussian footprints' spectra in
closed form (``footprint``), the residual flexibility of the modes not stepped
(``static_correction``), frames from the sine tables (``synthesis``) and initial shapes by the
discrete sine transform (``projection``). With int phi_k^2 = 2^-d the footprint-weighted
displacement is 2^-d s . q: ``scale`` is 2^-d.

A step is priced from its footprints' spectrum lengths before any is built (``cost``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.cost import FootprintSize, StepBudget, step_cost, tool_step_cost
from membrane_models.live.errors import InvalidLoad, InvalidProbe, LiveError
from membrane_models.live.footprint import (
    CACHE_BYTES,
    EDGE_CAP,
    EDGE_FREE,
    Footprint,
    edge_reach,
    gaussian_reach,
    make_footprint,
)
from membrane_models.live.footprint_memo import FootprintMemo
from membrane_models.live.free_step import one_factor
from membrane_models.live.inputs import inside_domain
from membrane_models.live.interface import Load, Probe
from membrane_models.live.modes import ModeSet
from membrane_models.live.projection import project
from membrane_models.live.static_correction import ResidualFlexibility
from membrane_models.live.synthesis import DENSE_TABLE_ELEMENTS, LatticeSynthesis
from membrane_models.sines import axis_sines

__all__ = ["DEFAULT_MAX_REACH", "SineBasis"]

FloatArray = NDArray[np.float64]

# Most modes per axis the static correction sums (the membrane's W table: 8 MiB; the string's:
# 2 MiB). They set the smallest footprint radius the correction carries: 4 / reach.
DEFAULT_MAX_REACH = {1: 2**18, 2: 2**10}


class SineBasis:
    """The sine basis on a lattice (``ModalBasis[Footprint]``).

    Args:
        c: the wave speed.
        modes: the stepped modes (``modes.choose_modes``).
        lattice: points per axis of the frames.
        max_reach: most modes per axis the static correction sums (at least the box).
        static_correction: add the static response of the modes not stepped.
    """

    def __init__(
        self,
        c: float,
        modes: ModeSet,
        lattice: tuple[int, ...],
        max_reach: int,
        static_correction: bool,
    ) -> None:
        self._dims = len(lattice)
        self._lattice = lattice
        self._modes = modes
        self.max_reach = max_reach
        self._edge_cap = min(max_reach, EDGE_CAP[self._dims])
        self.residual = ResidualFlexibility(c, modes, max_reach, static_correction)
        self.synthesis = LatticeSynthesis(lattice)
        self._scale = 0.5**self._dims
        self._axes = tuple(np.linspace(0.0, 1.0, n) for n in lattice)
        grid = np.meshgrid(*self._axes, indexing="ij")
        self._coordinates = np.stack(grid, axis=-1).reshape(-1, self._dims)
        self._coordinates.setflags(write=False)
        interior = np.ones(lattice, dtype=bool)
        for axis in range(self._dims):
            edges = [slice(None)] * self._dims
            edges[axis] = slice(0, None, max(lattice[axis] - 1, 1))
            interior[tuple(edges)] = False
        self._movable = interior.reshape(-1)
        # Recent steps' inputs and their footprints (a held probe, a held load, many sessions'
        # own): the same inputs get the same ones again (``footprint_memo``).
        self.memo: FootprintMemo[tuple[list[Footprint], list[Footprint | None]]] = FootprintMemo()
        self._last: tuple[object, tuple[list[Footprint], list[Footprint | None]]] | None = None
        self._movable.setflags(write=False)

    @property
    def spatial_dims(self) -> int:
        return self._dims

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        return self._lattice

    @property
    def modes(self) -> ModeSet:
        return self._modes

    @property
    def scale(self) -> float:
        return self._scale

    @property
    def static_correction(self) -> bool:
        return self.residual.enabled

    @property
    def min_radius(self) -> float:
        """The smallest footprint radius the static correction carries (0: a point, string)."""
        return smallest_radius(self.max_reach) if self.residual.enabled else 0.0

    @property
    def memory_bytes(self) -> int:
        """The residual weights and the sine tables held now."""
        return self.residual.nbytes + self.synthesis.nbytes

    @property
    def engine_bytes(self) -> int:
        """The residual weights and the sine tables at their largest, and the footprint caches
        every engine of the process shares."""
        weights = 8 * self.max_reach**self._dims if self.residual.enabled else self.residual.nbytes
        tables = sum(2 * 8 * DENSE_TABLE_ELEMENTS for _ in self._lattice)
        return weights + tables + CACHE_BYTES

    @property
    def lattice_coordinates(self) -> FloatArray:
        return self._coordinates

    @property
    def movable(self) -> NDArray[np.bool_]:
        """The lattice's interior (its edges are clamped)."""
        return self._movable

    @property
    def tool_force_radius(self) -> float:
        """Point forces on the string (finite there); on the membrane half the lattice's
        spacing, at least ``min_radius``: neighbouring points' footprints barely overlap (their
        weight at the next point is e^-4), so the points' compliance stays well conditioned."""
        if self._dims == 1:
            return 0.0
        spacing = min(1.0 / (n - 1) for n in self._lattice)
        return max(self.min_radius, 0.5 * spacing)

    contains = staticmethod(inside_domain)  # the unit interval or square

    def describe(self) -> dict[str, object]:
        return {
            "static_correction": self.residual.enabled,
            "max_reach": self.max_reach,
            "min_radius": self.min_radius,
        }

    # -- footprints -------------------------------------------------------------------------

    def footprints(
        self,
        loads: Sequence[Load],
        probes: Sequence[Probe],
        budget: StepBudget,
        *,
        tool_points: bool = False,
    ) -> tuple[list[Footprint], list[Footprint | None]]:
        """The loads' and probes' footprints (None: a probe outside the domain), the step's
        cost checked against ``budget`` first; inputs seen in a recent step get their
        footprints again (they are immutable) without building or pricing them twice."""
        key = (tuple(loads), tuple(probes), budget, tool_points)
        last = self._last
        if last is not None and last[0] == key:  # the usual case: no hashing, no lock
            return list(last[1][0]), list(last[1][1])
        found = self.memo.get(key)
        if found is None:
            found = self._footprints(loads, probes, budget, tool_points)
            prints = [fp for fp in (*found[0], *found[1]) if fp is not None]
            self.memo.put(key, found, sum(a.nbytes for fp in prints for a in fp.spectra))
        self._last = (key, found)
        return list(found[0]), list(found[1])

    def _footprints(
        self,
        loads: Sequence[Load],
        probes: Sequence[Probe],
        budget: StepBudget,
        tool_points: bool,
    ) -> tuple[list[Footprint], list[Footprint | None]]:
        load_sizes = [self.footprint_size(ld, "load", i) for i, ld in enumerate(loads)]
        probe_sizes = [
            self.footprint_size(pr, "probe", i) if inside_domain(pr.at) else None
            for i, pr in enumerate(probes)
        ]
        inside = [size for size in probe_sizes if size is not None]
        price = tool_step_cost if tool_points else step_cost
        budget.check(price(load_sizes, inside, self._lattice, self.residual.enabled))
        load_prints = [
            self.footprint(ld, size, "load") for ld, size in zip(loads, load_sizes, strict=True)
        ]
        kind = "tool point" if tool_points else "probe"
        probe_prints = [
            None if size is None else self.footprint(pr, size, kind)
            for pr, size in zip(probes, probe_sizes, strict=True)
        ]
        return load_prints, probe_prints

    def footprint_size(self, item: Load | Probe, kind: str, index: int) -> FootprintSize:
        """The spectrum entries a footprint needs per axis (long enough for the static
        correction), from its centre and radius alone: what the cost model prices.

        Raises:
            InvalidLoad, InvalidProbe: a radius below ``min_radius`` (or 0 on a membrane).
        """
        radius = item.radius
        if radius == 0.0:
            self._check_point(item, kind, index)
            return FootprintSize(self._modes.box, (0,) * self._dims)
        near = EDGE_FREE * radius
        edges = tuple(int(a < near) + int(1.0 - a < near) for a in item.at)
        if not self.residual.enabled:
            return FootprintSize(self._modes.box, edges)
        if radius < self.min_radius:  # before 4 / r, which overflows for subnormal radii
            raise self._too_small(item, kind, index)
        reach = gaussian_reach(radius)
        counts = tuple(
            max(k, reach, self._edge_reach(a, radius) if edge else 0)
            for k, a, edge in zip(self._modes.box, item.at, edges, strict=True)
        )
        return FootprintSize(counts, edges)

    def footprint(self, item: Load | Probe, size: FootprintSize, kind: str) -> Footprint:
        """The footprint of a load or probe, with ``size``'s spectrum entries per axis.

        Loads' spectra are cached (a load is usually held in place), probes' are not (they
        move every step, and the sines cost less than the bookkeeping).
        """
        if item.radius == 0.0:
            return self._point(item)
        return make_footprint(item.at, item.radius, size.counts, cache=kind != "probe")

    def modal_force(self, footprint: Footprint) -> FloatArray:
        """s on the stepped box: the footprint's spectra cut to it (their outer product)."""
        if self._dims == 1:
            return footprint.spectra[0][: self._modes.box[0]]
        kx, ky = self._modes.box
        return footprint.spectra[0][:kx, None] * footprint.spectra[1][None, :ky]

    def modal_factors(self, footprint: Footprint) -> tuple[FloatArray, FloatArray]:
        """``modal_force``'s factors: the spectra cut to the box (the string's second is [1])."""
        if self._dims == 1:
            return footprint.spectra[0][: self._modes.box[0]], one_factor()
        kx, ky = self._modes.box
        return footprint.spectra[0][:kx], footprint.spectra[1][:ky]

    # -- the static correction --------------------------------------------------------------

    def own(self, footprint: Footprint) -> float:
        return self.residual.own(footprint)

    def cross(self, a: Footprint, b: Footprint) -> float:
        return self.residual.cross(a, b)

    def loads_residual(
        self, prints: Sequence[Footprint], forces: Sequence[float]
    ) -> Callable[[Footprint], float]:
        """One combined box for the Gaussian loads (built once per step, whatever the number of
        probes), pairwise closed forms for point loads and point probes."""
        cross = self.residual.cross
        pairs = [(fp, f) for fp, f in zip(prints, forces, strict=True) if f != 0.0]
        if not pairs or not self.residual.enabled:
            return lambda probe: 0.0
        spread = [(fp, f) for fp, f in pairs if not fp.is_point]
        box = self.residual.combined(spread) if spread else None

        def residual(probe: Footprint) -> float:
            if probe.is_point:
                return sum(f * cross(fp, probe) for fp, f in pairs)
            total = 0.0 if box is None else self.residual.against(box, probe)
            return total + sum(f * cross(fp, probe) for fp, f in pairs if fp.is_point)

        return residual

    # -- frames and shapes ------------------------------------------------------------------

    def frame(self, q: FloatArray, applied: Sequence[tuple[Footprint, float]]) -> FloatArray:
        coefficients = q
        extra = []
        spread = []
        for footprint, force in applied:
            if force == 0.0 or not self.residual.enabled:
                continue
            if footprint.is_point:
                extra.append(self.residual.point_field(footprint.at[0], force, self.synthesis))
            else:
                spread.append((footprint, force))
        if spread:  # one combined box, however many footprints: the cost model's frame term
            coefficients = _add(coefficients, self.residual.combined(spread))
        values = self.synthesis.frame(coefficients)
        for field_values in extra:
            values = values + field_values
        return values

    def point_frame(
        self,
        points: NDArray[np.intp],
        q: FloatArray,
        applied: Sequence[tuple[Footprint, float]],
    ) -> FloatArray:
        coefficients = q
        spread = [(fp, f) for fp, f in applied if f != 0.0 and not fp.is_point]
        if spread and self.residual.enabled:
            coefficients = _add(coefficients, self.residual.combined(spread))
        values = self._at_points(coefficients, points)
        for footprint, force in applied:
            if force != 0.0 and footprint.is_point and self.residual.enabled:
                field_values = self.residual.point_field(footprint.at[0], force, self.synthesis)
                values = values + field_values[points]
        return values

    def point_compliance(
        self, points: NDArray[np.intp], prints: Sequence[Footprint], gain: FloatArray
    ) -> FloatArray:
        """sum_k phi_k(x_i) W_k s_j,k with W the stepped gain on the box and 1 / w^2 beyond
        (the static correction's weights), for every point i and footprint j; a point force on
        the string adds its closed-form residual instead."""
        counts = tuple(
            max([box, *(len(fp.spectra[a]) for fp in prints)])
            for a, box in enumerate(self._modes.box)
        )
        weights = np.array(self.residual.weights(counts)) if self.residual.enabled else None
        if weights is None:
            weights = np.zeros(counts)
        weights[tuple(slice(0, n) for n in gain.shape)] += gain
        rows = self._rows(points)
        if self._dims == 2:
            return self._separable(rows, weights, prints)
        spectra = self._padded(prints, 0, counts[0])
        table = axis_sines(self._axes[0][rows[0]], counts[0])
        compliance = table @ (weights[:, None] * spectra.T)
        for j, footprint in enumerate(prints):
            if footprint.is_point and self.residual.enabled:
                # the closed form carries every mode not stepped: the box's only the stepped
                stepped = table[:, : gain.size] @ (gain * spectra[j, : gain.size])
                unit = self.residual.point_field(footprint.at[0], 1.0, self.synthesis)
                compliance[:, j] = stepped + unit[points]
        return np.asarray(compliance)

    def project(self, shape: ArrayLike, what: str) -> tuple[FloatArray, float]:
        return project(shape, self._modes, self.synthesis, what)

    def _rows(self, points: NDArray[np.intp]) -> tuple[NDArray[np.intp], ...]:
        """Each point's index along each axis."""
        if self._dims == 1:
            return (points,)
        return tuple(np.unravel_index(points, self._lattice))

    def _at_points(self, coefficients: FloatArray, points: NDArray[np.intp]) -> FloatArray:
        """sum_m Z_m phi_m at lattice points: sine rows of the distinct lines they lie on."""
        rows = self._rows(points)
        if self._dims == 1:
            return np.asarray(axis_sines(self._axes[0][rows[0]], coefficients.size) @ coefficients)
        (ux, ix), (uy, iy) = (np.unique(r, return_inverse=True) for r in rows)
        tx = axis_sines(self._axes[0][ux], coefficients.shape[0])
        ty = axis_sines(self._axes[1][uy], coefficients.shape[1])
        return np.asarray((tx @ coefficients @ ty.T)[ix, iy])

    def _separable(
        self,
        rows: tuple[NDArray[np.intp], ...],
        weights: FloatArray,
        prints: Sequence[Footprint],
    ) -> FloatArray:
        """The membrane's point compliances, sum_mn X[a, c, m] W_mn Y[b, d, n] with X the sines
        of the points' x lines times the spectra of the footprints' x centres (Y alike): one
        matrix product over the distinct lines and centres, whatever the number of pairs."""
        (ux, ix), (uy, iy) = (np.unique(r, return_inverse=True) for r in rows)
        factors = []
        for axis, lines in enumerate((ux, uy)):
            centres, first, inverse = np.unique(
                [fp.at[axis] for fp in prints], return_index=True, return_inverse=True
            )
            count = weights.shape[axis]
            spectra = self._padded([prints[i] for i in first], axis, count)
            sines = axis_sines(self._axes[axis][lines], count)
            factors.append(((sines[:, None, :] * spectra[None, :, :]), inverse, centres.size))
        (ax, jx, cx), (ay, jy, cy) = factors
        gx, gy = ax.shape[0], ay.shape[0]
        both = ax.reshape(gx * cx, -1) @ weights @ ay.reshape(gy * cy, -1).T
        both = both.reshape(gx, cx, gy, cy)
        return np.asarray(both[ix[:, None], jx[None, :], iy[:, None], jy[None, :]])

    @staticmethod
    def _padded(prints: Sequence[Footprint], axis: int, count: int) -> FloatArray:
        """The footprints' spectra along ``axis``, zero-padded to ``count`` entries."""
        out = np.zeros((len(prints), count))
        for row, footprint in enumerate(prints):
            spectrum = footprint.spectra[axis]
            out[row, : len(spectrum)] = spectrum
        return out

    # -- helpers ----------------------------------------------------------------------------

    def _too_small(self, item: Load | Probe, kind: str, index: int) -> LiveError:
        error = InvalidLoad if isinstance(item, Load) else InvalidProbe
        return error(
            f"{kind} {index}: radius {item.radius:.6g} is below {self.min_radius:.3g}, the "
            f"smallest the static correction carries (modes up to 4 / r, at most "
            f"{self.max_reach} per axis){'; 0 is a point force' if self._dims == 1 else ''}"
        )

    def _edge_reach(self, centre: float, radius: float) -> int:
        return min(self._edge_cap, edge_reach(centre, radius))

    def _check_point(self, item: Load | Probe, kind: str, index: int) -> None:
        if self._dims == 2:
            error = InvalidLoad if isinstance(item, Load) else InvalidProbe
            raise error(
                f"{kind} {index}: radius 0 on a membrane: a point force's displacement is "
                "logarithmically singular there (infinite under the point); give the tool's "
                "radius (> 0; the study's forcing is 0.05)"
            )

    def _point(self, item: Load | Probe) -> Footprint:
        """A point force (string only); on a clamped end it touches nothing."""
        if item.at[0] in (0.0, 1.0):
            zero = np.zeros(self._modes.box[0])
            zero.setflags(write=False)
            return Footprint(item.at, 0.0, (zero,))
        return make_footprint(item.at, 0.0, self._modes.box)


def smallest_radius(reach: int) -> float:
    """The smallest radius whose Gaussian spectrum fits in ``reach`` modes."""
    radius = 4.0 / reach
    while gaussian_reach(radius) > reach:  # ceil(4 / r) <= reach, despite rounding
        radius = math.nextafter(radius, math.inf)
    return radius


def _add(a: FloatArray, b: FloatArray) -> FloatArray:
    """a + b on the larger of their boxes (each starts at mode 1 on every axis)."""
    shape = tuple(max(x, y) for x, y in zip(a.shape, b.shape, strict=True))
    if b.shape == shape:
        out = b.copy()
        out[tuple(slice(0, n) for n in a.shape)] += a
        return out
    out = np.zeros(shape)
    out[tuple(slice(0, n) for n in a.shape)] += a
    out[tuple(slice(0, n) for n in b.shape)] += b
    return out
