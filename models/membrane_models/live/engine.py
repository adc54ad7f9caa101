"""The exact modal engine: the string's and the membrane's response to live loads and probes.

The response to any load history is a sum over the sine modes; each is a damped oscillator
q'' + 2 zeta w q' + w^2 q = p, p the modal force. The engine keeps the modes its lattice and its
step resolve (``modes``), advances each exactly by a 2 x 2 transition per step (``transition``:
zero-order hold by default, first-order hold for loads that ramp between steps), adds the static
response of the modes it does not step (``static_correction``), solves probe contact exactly at
the end of each step (``contact``) and synthesises the frame on the lattice (``synthesis``).

Scaling: with u = sum q_k phi_k and int phi_k^2 = 2^-d, the modal force of a pressure F g is
p_k = F s_k with s_k = 2^d <g, phi_k> (``footprint``), the footprint-weighted displacement is
z = <g, u> = 2^-d s . q, and the energy of the stepped modes is 2^-d / 2 sum (v^2 + w^2 q^2)
(density 1, problem units).

Per step (zero-order hold; first-order hold ramps the loads' modal force from the last step's):

1. the loads' modal force p at the end of the step; the free step q_f, v_f;
2. each probe's free displacement z_f = 2^-d s . q_f + sum_loads F r(load, probe) and the
   one-step compliance C_ij = 2^-d sum G_q s_i s_j + r(i, j), r the residual flexibility;
3. the contact forces from the complementarity problem, applied over the step
   (q = q_f - sum F_j G_q s_j, and so for v);
4. the frame: the stepped modes plus the static response of the others to every force acting.

Contact forces are held over the step under either hold: they are this step's unknowns.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.contact import single_contact, solve_contact
from membrane_models.live.cost import FootprintSize, StepBudget, step_cost
from membrane_models.live.errors import (
    InvalidEngineSettings,
    InvalidLoad,
    InvalidProbe,
    InvalidState,
    LiveError,
)
from membrane_models.live.footprint import (
    CACHE_BYTES,
    EDGE_CAP,
    EDGE_FREE,
    Footprint,
    edge_reach,
    gaussian_reach,
    make_footprint,
)
from membrane_models.live.inputs import (
    MAX_DEPTH,
    MAX_FORCE,
    MAX_LOADS,
    MAX_PROBES,
    MAX_RADIUS,
    inside_domain,
    parse_loads,
    parse_probes,
)
from membrane_models.live.interface import (
    ENGINE_INPUTS,
    Hold,
    Load,
    Probe,
    ProbeReading,
    Start,
    StepResult,
)
from membrane_models.live.modes import ModeSet, choose_modes
from membrane_models.live.projection import MAX_SHAPE_VALUE, project
from membrane_models.live.static_correction import ResidualFlexibility
from membrane_models.live.synthesis import DENSE_TABLE_ELEMENTS, LatticeSynthesis
from membrane_models.live.transition import Transition, transition
from membrane_models.problems import Problem

__all__ = ["DEFAULT_MAX_REACH", "MAX_LATTICE_POINTS", "ModalEngine", "ModalState"]

FloatArray = NDArray[np.float64]

MAX_LATTICE_POINTS = 2**22
# Python objects around a state's arrays (the dataclass, tuples, array headers), and around each
# applied footprint (its dataclass, tuples, array headers): tracemalloc's figures, rounded up.
_STATE_OVERHEAD = 2048
_FOOTPRINT_OVERHEAD = 768
# Most modes per axis the static correction sums (the membrane's W table: 8 MiB; the string's:
# 2 MiB). They set the smallest footprint radius the correction carries: 4 / reach.
DEFAULT_MAX_REACH = {1: 2**18, 2: 2**10}
_NAN = math.nan


@dataclass(frozen=True)
class ModalState:
    """A modal engine's state: immutable, so a refused or retried step leaves it as it was.

    Attributes:
        step: steps taken.
        time: step * dt.
        q, v: the stepped modes' amplitudes and velocities (on the engine's mode box, 0 off it).
        load_force: the loads' modal force at the end of the last step (where a first-order
            hold starts the next ramp).
        applied: the forces acting at the end of the last step, with their footprints (the
            static correction's share of the frame).
    """

    step: int
    time: float
    q: FloatArray
    v: FloatArray
    load_force: FloatArray
    applied: tuple[tuple[Footprint, float], ...] = ()
    owner: object = field(default=None, repr=False, compare=False)


class ModalEngine:
    """The exact modal live engine for the string (d = 1) and the membrane (d = 2).

    Args:
        problem: the scene's problem; its wave speed ``c`` and dimension are used.
        lattice: points per axis of the frames (an int: the same on every axis), >= 3 each,
            on the uniform grid linspace(0, 1, n) per axis.
        dt: the step (problem time units), > 0.
        damping: modal damping ratio zeta >= 0 (0: the study's equation).
        hold: "zoh" (loads constant over a step) or "foh" (linear from the last step's).
        modes: modes per axis to step (default: those the lattice resolves, n - 2).
        step_limit: keep modes with w dt <= step_limit (default pi); None keeps all.
        static_correction: add the static response of the modes not stepped.
        max_reach: most modes per axis the static correction sums (default
            ``DEFAULT_MAX_REACH``); the smallest radius it carries is 4 / max_reach.
        budget: the most one step may cost (``cost.StepBudget``; default 5 ms of work and
            512 KiB of held spectra); a step over it is refused with its figure.

    Raises:
        InvalidEngineSettings: a setting out of range.
    """

    def __init__(
        self,
        problem: Problem,
        lattice: int | Sequence[int],
        dt: float,
        *,
        damping: float = 0.0,
        hold: Hold = "zoh",
        modes: int | Sequence[int] | None = None,
        step_limit: float | None = math.pi,
        static_correction: bool = True,
        max_reach: int | None = None,
        budget: StepBudget | None = None,
    ) -> None:
        dims = problem.spatial_dims
        if dims not in (1, 2):
            raise InvalidEngineSettings(f"{problem.name}: only strings and membranes are live")
        self.problem = problem
        self._dims = dims
        self._c = float(problem.c)
        self._lattice = _lattice(lattice, dims)
        self._dt = _positive(dt, "dt")
        self.damping = _damping(damping)
        if hold not in ("zoh", "foh"):
            raise InvalidEngineSettings(f"hold must be 'zoh' or 'foh', got {str(hold)[:20]!r}")
        self.hold: Hold = hold
        limit = None if step_limit is None else _positive(step_limit, "step_limit")
        counts = None if modes is None else _counts(modes, dims, "modes")
        self.modes: ModeSet = choose_modes(self._c, self._lattice, self._dt, counts, limit)
        reach = DEFAULT_MAX_REACH[dims] if max_reach is None else max_reach
        reach = max(_counts(reach, 1, "max_reach")[0], *self.modes.box, 1)
        self.max_reach = reach
        self._edge_cap = min(reach, EDGE_CAP[dims])
        self.transition: Transition = _masked(
            transition(self.modes.omega, self.damping, self._dt), self.modes.kept
        )
        self.residual = ResidualFlexibility(self._c, self.modes, reach, static_correction)
        self.synthesis = LatticeSynthesis(self._lattice)
        self.budget = budget if budget is not None else StepBudget()
        self._scale = 0.5**dims
        self._owner = object()
        self._zeros = np.zeros(self.modes.box)
        self._zeros.setflags(write=False)
        self._energy_weights = self._scale * 0.5 * np.where(self.modes.kept, self.modes.omega**2, 0)

    # -- the interface ----------------------------------------------------------------------

    @property
    def spatial_dims(self) -> int:
        return self._dims

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        return self._lattice

    @property
    def dt(self) -> float:
        return self._dt

    @property
    def inputs(self) -> frozenset[str]:
        """Loads, probes and initial shapes: everything the interface offers."""
        return ENGINE_INPUTS

    @property
    def min_radius(self) -> float:
        """The smallest footprint radius the static correction carries (0: a point, string)."""
        return _smallest_radius(self.max_reach) if self.residual.enabled else 0.0

    @property
    def memory_bytes(self) -> int:
        """Bytes held: transition coefficients, the residual weights, the sine tables."""
        return self._coefficient_bytes + self.residual.nbytes + self.synthesis.nbytes

    @property
    def _coefficient_bytes(self) -> int:
        """The transition's coefficients and the modes' frequencies (fixed at build)."""
        arrays = [getattr(self.transition, name) for name in self.transition.__dataclass_fields__]
        return sum(int(a.nbytes) for a in arrays) + int(self.modes.omega.nbytes)

    def start(
        self, displacement: ArrayLike | None = None, velocity: ArrayLike | None = None
    ) -> Start[ModalState]:
        """The state at t = 0, at rest or from shapes on the lattice (least-squares projection).

        Raises:
            InvalidShape: a shape of the wrong size, or with NaN or inf.
        """
        q, q_residual = self._project(displacement, "displacement")
        v, v_residual = self._project(velocity, "velocity")
        state = ModalState(0, 0.0, q, v, self._zeros, (), self._owner)
        return Start(state, q_residual, v_residual)

    def step(
        self,
        state: ModalState,
        loads: Sequence[Load] = (),
        probes: Sequence[Probe] = (),
        *,
        frame: bool = True,
        work: bool = False,
    ) -> StepResult[ModalState]:
        """One step under ``loads`` (held or ramped) and ``probes`` (contact at its end).

        Args:
            frame: synthesise the frame (a haptic loop asks for one every few steps).
            work: report the work done on the stepped modes (zero-order hold only).

        Raises:
            InvalidLoad, InvalidProbe: bad input; ``state`` is unchanged (it always is).
            InvalidState: a state from another engine.
        """
        self._check(state)
        checked_loads = parse_loads(loads, self._dims) if loads else ()
        checked_probes = parse_probes(probes, self._dims) if probes else ()
        load_sizes = [self.footprint_size(ld, "load", i) for i, ld in enumerate(checked_loads)]
        probe_sizes = [
            self.footprint_size(pr, "probe", i) if inside_domain(pr.at) else None
            for i, pr in enumerate(checked_probes)
        ]
        inside = [size for size in probe_sizes if size is not None]
        self.budget.check(step_cost(load_sizes, inside, self._lattice, self.residual.enabled))
        pairs = zip(checked_loads, load_sizes, strict=True)
        load_prints = [self._footprint(ld, size, "load") for ld, size in pairs]
        probe_prints = [
            None if size is None else self._footprint(pr, size, "probe")
            for pr, size in zip(checked_probes, probe_sizes, strict=True)
        ]
        load_forces = [ld.force for ld in checked_loads]
        tr, q0, v0 = self.transition, state.q, state.v
        p1 = self._modal_force(load_prints, load_forces)
        q = tr.qq * q0
        q += tr.qv * v0
        v = tr.vq * q0
        v += tr.vv * v0
        if self.hold == "foh":
            p0 = state.load_force
            q += tr.foh0_q * p0 + tr.foh1_q * p1
            v += tr.foh0_v * p0 + tr.foh1_v * p1
        elif load_prints:
            q += tr.zoh_q * p1
            v += tr.zoh_v * p1
        readings, contact = self._contact(
            q, v, checked_probes, probe_prints, load_prints, load_forces
        )
        done = self._work(p1, contact, q, q0) if work and self.hold == "zoh" else None
        applied = [*zip(load_prints, load_forces, strict=True)]
        for fp, reading in zip(probe_prints, readings, strict=True):
            if fp is not None and reading.force > 0.0:
                applied.append((fp, -reading.force))
        _require_finite(q, v, readings)
        q.flags.writeable = v.flags.writeable = p1.flags.writeable = False
        index = state.step + 1
        new = ModalState(index, index * self._dt, q, v, p1, tuple(applied), self._owner)
        return StepResult(new, self.frame(new) if frame else None, readings, done)

    def _work(
        self,
        load_force: FloatArray,
        contact: Sequence[tuple[FloatArray, float]],
        q: FloatArray,
        q0: FloatArray,
    ) -> float:
        """Work on the stepped modes over a held step: 2^-d sum p (q1 - q0), p all forces'."""
        total = load_force.copy()
        for s, force in contact:
            total -= force * s
        return self._scale * float(np.vdot(total, q - q0))

    def frame(self, state: ModalState) -> FloatArray:
        """Displacements on the lattice (x-major, flattened): stepped modes plus correction."""
        self._check(state)
        coefficients = state.q
        extra = []
        spread = []
        for footprint, force in state.applied:
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

    def energy(self, state: ModalState) -> float:
        """Kinetic plus strain energy of the stepped modes: 2^-d / 2 sum (v^2 + w^2 q^2)."""
        self._check(state)
        kinetic = self._scale * 0.5 * float(np.vdot(state.v, state.v))
        return kinetic + float(np.vdot(self._energy_weights, state.q * state.q))

    def describe(self) -> dict[str, object]:
        """The engine's settings and sizes, as plain data."""
        return {
            "engine": "modal",
            "inputs": sorted(self.inputs),
            "problem": self.problem.name,
            "lattice": list(self._lattice),
            "dt": self._dt,
            "damping": self.damping,
            "hold": self.hold,
            "modes_stepped": self.modes.count,
            "mode_box": list(self.modes.box),
            "static_correction": self.residual.enabled,
            "max_reach": self.max_reach,
            "min_radius": self.min_radius,
            "memory_bytes": self.memory_bytes,
            "max_step_work": self.budget.max_work,
            "max_held_bytes": self.budget.max_held_bytes,
            "max_force": MAX_FORCE,
            "max_depth": MAX_DEPTH,
            "max_radius": MAX_RADIUS,
            "max_shape_value": MAX_SHAPE_VALUE,
            "engine_bytes": self.engine_bytes,
            "state_bytes": self.state_bytes,
        }

    @property
    def engine_bytes(self) -> int:
        """The most this engine and the footprint caches it shares hold, whatever sessions send:
        its coefficients, the residual weights and the sine tables at their largest."""
        weights = 8 * self.max_reach**self._dims if self.residual.enabled else self.residual.nbytes
        tables = sum(2 * 8 * DENSE_TABLE_ELEMENTS for _ in self._lattice)
        return self._coefficient_bytes + weights + tables + CACHE_BYTES

    @property
    def state_bytes(self) -> int:
        """The most one state holds: q, v and the held load force on the mode box, and the
        applied footprints' spectra within the budget (with their objects)."""
        arrays = 3 * 8 * math.prod(self.modes.box)
        footprints = (MAX_LOADS + MAX_PROBES) * _FOOTPRINT_OVERHEAD
        return arrays + self.budget.max_held_bytes + footprints + _STATE_OVERHEAD

    # -- the parts of a step ----------------------------------------------------------------

    def footprint_size(self, item: Load | Probe, kind: str, index: int) -> FootprintSize:
        """The spectrum entries a footprint needs per axis (long enough for the static
        correction), from its centre and radius alone: what the cost model prices.

        Raises:
            InvalidLoad, InvalidProbe: a radius below ``min_radius`` (or 0 on a membrane).
        """
        radius = item.radius
        if radius == 0.0:
            self._check_point(item, kind, index)
            return FootprintSize(self.modes.box, (0,) * self._dims)
        near = EDGE_FREE * radius
        edges = tuple(int(a < near) + int(1.0 - a < near) for a in item.at)
        if not self.residual.enabled:
            return FootprintSize(self.modes.box, edges)
        if radius < self.min_radius:  # before 4 / r, which overflows for subnormal radii
            raise self._too_small(item, kind, index)
        reach = gaussian_reach(radius)
        counts = tuple(
            max(k, reach, self._edge_reach(a, radius) if edge else 0)
            for k, a, edge in zip(self.modes.box, item.at, edges, strict=True)
        )
        return FootprintSize(counts, edges)

    def _footprint(self, item: Load | Probe, size: FootprintSize, kind: str) -> Footprint:
        """The footprint of a load or probe, with ``size``'s spectrum entries per axis.

        Loads' spectra are cached (a load is usually held in place), probes' are not (they
        move every step, and the sines cost less than the bookkeeping).
        """
        if item.radius == 0.0:
            return self._point(item)
        return make_footprint(item.at, item.radius, size.counts, cache=kind == "load")

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
            zero = np.zeros(self.modes.box[0])
            zero.setflags(write=False)
            return Footprint(item.at, 0.0, (zero,))
        return make_footprint(item.at, 0.0, self.modes.box)

    def _box_force(self, footprint: Footprint) -> FloatArray:
        """s on the stepped box: the footprint's modal force per unit force."""
        if self._dims == 1:
            return footprint.spectra[0][: self.modes.box[0]]
        kx, ky = self.modes.box
        return footprint.spectra[0][:kx, None] * footprint.spectra[1][None, :ky]

    def _modal_force(self, prints: Sequence[Footprint], forces: Sequence[float]) -> FloatArray:
        if not prints:
            return self._zeros
        total = forces[0] * self._box_force(prints[0])
        for footprint, force in zip(prints[1:], forces[1:], strict=True):
            total += force * self._box_force(footprint)
        return np.asarray(total)

    def _contact(
        self,
        q: FloatArray,
        v: FloatArray,
        probes: Sequence[Probe],
        prints: Sequence[Footprint | None],
        load_prints: Sequence[Footprint],
        load_forces: Sequence[float],
    ) -> tuple[tuple[ProbeReading, ...], list[tuple[FloatArray, float]]]:
        """Solve contact, apply it to q and v in place; the readings and (s, F) per contact."""
        footprints = [fp for fp in prints if fp is not None]
        if not footprints:
            return tuple(_outside() for _ in probes), []
        tr, cross, scale = self.transition, self.residual.cross, self._scale
        from_loads = self._loads_residual(load_prints, load_forces)
        if len(probes) == 1:
            return self._one_probe(q, v, probes[0], footprints[0], from_loads)
        shapes = [self._box_force(fp) for fp in footprints]
        gains = [tr.zoh_q * s for s in shapes]  # the end-of-step response to a unit force
        count = len(footprints)
        free = np.empty(count)
        compliance = np.empty((count, count))
        for j, (s, fp) in enumerate(zip(shapes, footprints, strict=True)):
            free[j] = scale * float(np.vdot(s, q)) + from_loads(fp)
            for k in range(j + 1):
                value = scale * float(np.vdot(gains[j], shapes[k])) + cross(fp, footprints[k])
                compliance[j, k] = compliance[k, j] = value
        depths = np.array([pr.depth for pr, fp in zip(probes, prints, strict=True) if fp])
        forces = solve_contact(compliance, free + depths)
        contact = []
        for s, gain, force in zip(shapes, gains, forces, strict=True):
            if force > 0.0:
                q -= force * gain
                v -= (force * tr.zoh_v) * s
                contact.append((s, float(force)))
        displacement = free - compliance @ forces
        found = iter(
            _reading(float(f), float(z), float(d), float(compliance[j, j]))
            for j, (f, z, d) in enumerate(zip(forces, displacement, depths, strict=True))
        )
        readings = tuple(next(found) if fp else _outside() for fp in prints)
        return readings, contact

    def _one_probe(
        self,
        q: FloatArray,
        v: FloatArray,
        probe: Probe,
        footprint: Footprint,
        from_loads: Callable[[Footprint], float],
    ) -> tuple[tuple[ProbeReading, ...], list[tuple[FloatArray, float]]]:
        """``_contact`` for the haptic loop's one probe, in scalars: F = max(0, b / c)."""
        tr = self.transition
        s = self._box_force(footprint)
        gain = tr.zoh_q * s
        free = self._scale * float(np.vdot(s, q)) + from_loads(footprint)
        compliance = self._scale * float(np.vdot(gain, s)) + self.residual.own(footprint)
        force = single_contact(compliance, free + probe.depth)
        if force == 0.0:
            return (_reading(0.0, free, probe.depth, compliance),), []
        q -= force * gain
        v -= (force * tr.zoh_v) * s
        return (_reading(force, free - compliance * force, probe.depth, compliance),), [(s, force)]

    def _loads_residual(
        self, prints: Sequence[Footprint], forces: Sequence[float]
    ) -> Callable[[Footprint], float]:
        """The loads' residual displacement under a probe's footprint: one combined box for
        the Gaussian loads (built once per step, whatever the number of probes), pairwise
        closed forms for point loads and point probes."""
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

    def _project(self, shape: ArrayLike | None, what: str) -> tuple[FloatArray, float]:
        if shape is None:
            return self._zeros, 0.0
        box, residual = project(shape, self.modes, self.synthesis, what)
        box.setflags(write=False)
        return box, residual

    def _check(self, state: ModalState) -> None:
        if not isinstance(state, ModalState) or state.owner is not self._owner:
            raise InvalidState("this state was not made by this engine (use its start())")


def _smallest_radius(reach: int) -> float:
    """The smallest radius whose Gaussian spectrum fits in ``reach`` modes."""
    radius = 4.0 / reach
    while gaussian_reach(radius) > reach:  # ceil(4 / r) <= reach, despite rounding
        radius = math.nextafter(radius, math.inf)
    return radius


def _require_finite(q: FloatArray, v: FloatArray, readings: Sequence[ProbeReading]) -> None:
    """Refuse a step whose response overflowed (inputs within their bounds never do; this is
    the guarantee that no state holds inf or NaN)."""
    if not (np.isfinite(q).all() and np.isfinite(v).all()):
        raise InvalidLoad("this step's response is not finite: its forces or depths are too large")
    if not all(math.isfinite(r.force) for r in readings):
        raise InvalidProbe("this step's contact forces are not finite: its depths are too large")


def _reading(force: float, displacement: float, depth: float, compliance: float) -> ProbeReading:
    gap = 0.0 if force > 0.0 else -(displacement + depth)
    return ProbeReading(force, displacement, gap, compliance, force > 0.0)


def _outside() -> ProbeReading:
    return ProbeReading(0.0, _NAN, _NAN, _NAN, False, True)


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


def _masked(tr: Transition, kept: NDArray[np.bool_]) -> Transition:
    """The transition with every coefficient 0 off the kept modes (they stay at rest)."""
    arrays = {}
    for name in tr.__dataclass_fields__:
        array = np.where(kept, getattr(tr, name), 0.0)
        array.setflags(write=False)
        arrays[name] = array
    return Transition(**arrays)


def _lattice(lattice: int | Sequence[int], dims: int) -> tuple[int, ...]:
    counts = _counts(lattice, dims, "lattice")
    if any(n < 3 for n in counts):
        raise InvalidEngineSettings(f"the lattice needs >= 3 points per axis, got {counts}")
    if math.prod(counts) > MAX_LATTICE_POINTS:
        raise InvalidEngineSettings(f"the lattice has more than {MAX_LATTICE_POINTS} points")
    return counts


def _counts(value: int | Sequence[int], dims: int, what: str) -> tuple[int, ...]:
    values = [value] * dims if isinstance(value, int) else list(value)
    if len(values) != dims or not all(
        isinstance(n, int | np.integer) and not isinstance(n, bool) and n >= 1 for n in values
    ):
        raise InvalidEngineSettings(f"{what} must be {dims} positive integer(s)")
    return tuple(int(n) for n in values)


def _positive(value: float, what: str) -> float:
    number = float(value)
    if not (math.isfinite(number) and number > 0.0):
        raise InvalidEngineSettings(f"{what} must be a finite number > 0, got {number:.6g}")
    return number


def _damping(value: float) -> float:
    number = float(value)
    if not (math.isfinite(number) and number >= 0.0):
        raise InvalidEngineSettings(f"damping must be a finite ratio >= 0, got {number:.6g}")
    return number
