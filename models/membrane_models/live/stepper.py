"""The stepping core: damped modal oscillators under loads and probes, over any modal basis.

Each mode is a damped oscillator q'' + 2 zeta w q' + w^2 q = p, p the modal force. The core
advances every stepped mode exactly by a 2 x 2 transition per step (``transition``: zero-order
hold by default, first-order hold for loads that ramp between steps), solves probe contact
exactly at the end of each step (``contact``) and asks the basis (``basis.ModalBasis``) for
everything that depends on the modes: footprints, the static correction, frames and initial
shapes. The sine engine (``engine.ModalEngine``) is this core over the sine basis; FEM modes
plug in as a tabulated basis (``tabulated_basis``).

With s a footprint's modal force per unit force and ``scale`` the basis's weight, the
footprint-weighted displacement of the stepped modes is z = scale s . q and their energy
scale / 2 sum (v^2 + w^2 q^2).

Per step (zero-order hold; first-order hold ramps the loads' modal force from the last step's):

1. the loads' modal force p at the end of the step; the free step q_f, v_f;
2. each probe's free displacement z_f = scale s . q_f + sum_loads F r(load, probe) and the
   one-step compliance C_ij = scale sum G_q s_i s_j + r(i, j), r the static correction's;
3. the contact forces from the complementarity problem, applied over the step
   (q = q_f - sum F_j G_q s_j, and so for v);
4. the frame: the stepped modes plus the static response of the others to every force acting.

Rigid tools (``tools``) replace step 2 and 3 by their points' problem: the free frame at the
lattice points under them, their one-step compliance to the points' footprints (the basis's
``point_frame`` and ``point_compliance``, what the frame will show), and the complementarity
problem on that non-symmetric P-matrix (``contact.solve_points``).

Contact forces are held over the step under either hold: they are this step's unknowns.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, NamedTuple, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.basis import FootprintT, ModalBasis
from membrane_models.live.contact import (
    single_contact,
    solve_contact,
    solve_mixed,
    solve_points,
)
from membrane_models.live.cost import StepBudget
from membrane_models.live.errors import (
    InvalidEngineSettings,
    InvalidLoad,
    InvalidProbe,
    InvalidState,
    InvalidTool,
    LiveError,
)
from membrane_models.live.free_step import FreeStepKernel, stacked_transition
from membrane_models.live.inputs import (
    MAX_DEPTH,
    MAX_FORCE,
    MAX_LOADS,
    MAX_PROBES,
    MAX_RADIUS,
    MAX_TOOL_POINTS,
    MAX_TOOLS,
    parse_grasps,
    parse_loads,
    parse_probes,
    parse_tools,
)
from membrane_models.live.interface import (
    ENGINE_INPUTS,
    TOOL_KINDS,
    Grasp,
    GraspReading,
    Hold,
    Load,
    Probe,
    ProbeReading,
    Start,
    StepResult,
    Tool,
)
from membrane_models.live.projection import MAX_SHAPE_VALUE
from membrane_models.live.tools import ToolPoints, tool_points, tool_readings
from membrane_models.live.transition import Transition, transition

__all__ = ["Advanced", "ModalState", "ModalStepper", "StepRows"]

FloatArray = NDArray[np.float64]
# A step's end before it is checked and kept: q, v, the loads' modal force, and its contact.
Advanced = tuple[FloatArray, FloatArray, FloatArray, Any]

# Python objects around a state's arrays (the dataclass, tuples, array headers), and around each
# applied footprint (its dataclass, tuples, array headers): tracemalloc's figures, rounded up.
_STATE_OVERHEAD = 2048
_FOOTPRINT_OVERHEAD = 768
_NAN = math.nan


@dataclass(frozen=True)
class ModalState:
    """A modal engine's state: immutable, so a refused or retried step leaves it as it was.

    Attributes:
        step: steps taken.
        time: step * dt.
        q, v: the stepped modes' amplitudes and velocities (on the basis's mode box, 0 off it).
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
    applied: tuple[tuple[Any, float], ...] = ()
    owner: object = field(default=None, repr=False, compare=False)


class StepRows(NamedTuple):
    """A step's inputs as its modes see them, for an engine that solves for its step's end
    (``ModalStepper._solve_step``), with the contact as ``_contact`` solves it at the end.

    Row j (a probe or grasp on the domain) reads z_j = scale s_j . q + offsets_j
    - sum_k residual_jk F_k at the step's end, F_k the rows' forces (along -axis). A probe keeps
    z_j <= -depths_j with F_j >= 0 (complementary), a grasp holds z_j = -depths_j (F_j of either
    sign); F pushes the modes by -sum F_j s_j over the step.

    Attributes:
        load_force: the loads' modal force at the step's end (held over it: zero-order hold).
        shapes: each row's modal force per unit force s_j (on the mode box).
        depths: d_j per row (a grasp's: minus its height).
        held: which rows are grasps.
        offsets: the loads' static correction under each row (0 without it).
        residual: the static correction's compliance between the rows (0 without it).
        scale: the basis's weight.
    """

    load_force: FloatArray
    shapes: tuple[FloatArray, ...]
    depths: tuple[float, ...]
    held: tuple[bool, ...]
    offsets: tuple[float, ...]
    residual: tuple[tuple[float, ...], ...]
    scale: float


class ModalStepper(Generic[FootprintT]):
    """The live engine over a modal basis (``LiveEngine[ModalState]``).

    Args:
        basis: the modes, their footprints, static correction and frames.
        dt: the step (the basis's time units), > 0.
        damping: modal damping ratio zeta >= 0: one for every mode, or one per mode (an array
            of the mode box's shape, e.g. Rayleigh damping's alpha / 2w + beta w / 2).
        hold: "zoh" (loads constant over a step) or "foh" (linear from the last step's).
        budget: the most one step may cost (``cost.StepBudget``; default 5 ms of work and
            512 KiB of held spectra); a step over it is refused with its figure.
        kind: the engine kind ``describe`` names (its ``membrane.engines`` entry).

    Raises:
        InvalidEngineSettings: a setting out of range.
    """

    def __init__(
        self,
        basis: ModalBasis[FootprintT],
        dt: float,
        *,
        damping: float | ArrayLike = 0.0,
        hold: Hold = "zoh",
        budget: StepBudget | None = None,
        kind: str = "modal",
    ) -> None:
        self.basis = basis
        self.kind = kind
        self._dims = basis.spatial_dims
        self._lattice = basis.lattice_shape
        self._dt = positive(dt, "dt")
        self.damping: float | FloatArray = (
            damping_ratio(damping)  # type: ignore[arg-type]
            if np.ndim(damping) == 0
            else damping_ratios(damping, basis.modes.box)
        )
        if hold not in ("zoh", "foh"):
            raise InvalidEngineSettings(f"hold must be 'zoh' or 'foh', got {str(hold)[:20]!r}")
        self.hold: Hold = hold
        self.modes = basis.modes
        self.transition, block = stacked_transition(
            _masked(transition(self.modes.omega, self.damping, self._dt), self.modes.kept)
        )
        self._free_kernel = FreeStepKernel(block, hold)
        self.budget = budget if budget is not None else StepBudget()
        self._scale = basis.scale
        self._owner = object()
        self._zeros = np.zeros(self.modes.box)
        self._zeros.setflags(write=False)
        self._energy_weights = self._scale * 0.5 * np.where(self.modes.kept, self.modes.omega**2, 0)
        # a footprint's static compliance over the stepped modes: scale sum s_k^2 / w_k^2
        self._static_weights = self._scale * np.where(self.modes.kept, self.modes.omega**-2.0, 0)

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
    def memory_bytes(self) -> int:
        """Bytes held: transition coefficients and the basis's tables."""
        return self._coefficient_bytes + self.basis.memory_bytes

    @property
    def _coefficient_bytes(self) -> int:
        """The transition's coefficients and the modes' frequencies (fixed at build)."""
        arrays = [getattr(self.transition, name) for name in self.transition.__dataclass_fields__]
        return sum(int(a.nbytes) for a in arrays) + int(self.modes.omega.nbytes)

    @property
    def engine_bytes(self) -> int:
        """The most this engine and the caches it shares hold, whatever sessions send."""
        return self._coefficient_bytes + self.basis.engine_bytes

    @property
    def state_bytes(self) -> int:
        """The most one state holds: q, v and the held load force on the mode box, and the
        applied footprints' spectra within the budget (with their objects)."""
        arrays = 3 * 8 * math.prod(self.modes.box)
        footprints = (MAX_LOADS + max(MAX_PROBES, MAX_TOOLS * MAX_TOOL_POINTS)) * (
            _FOOTPRINT_OVERHEAD
        )
        return arrays + self.budget.max_held_bytes + footprints + _STATE_OVERHEAD

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
        grasps: Sequence[Grasp] = (),
        tools: Sequence[Tool] = (),
    ) -> StepResult[ModalState]:
        """One step under ``loads`` (held or ramped), ``probes`` (contact at its end) and
        ``grasps`` (held exactly at their heights at its end, with the probes' contact), or
        rigid ``tools`` (no lattice point under one above its surface at the step's end).

        Args:
            frame: synthesise the frame (a haptic loop asks for one every few steps).
            work: report the work done on the stepped modes (zero-order hold only).

        Raises:
            InvalidLoad, InvalidProbe, InvalidGrasp, InvalidTool: bad input; ``state`` is
                unchanged (it always is).
            InvalidState: a state from another engine.
        """
        self._check(state)
        if tools:
            return self._step_tools(state, loads, tools, probes, grasps, frame, work)
        if not (probes or grasps or work) and self._fixed_transition:
            return self._load_step(state, loads, frame)  # what ``step_loads`` does per state
        basis = self.basis
        checked_loads = parse_loads(loads, self._dims, basis.contains) if loads else ()
        checked_probes = parse_probes(probes, self._dims) if probes else ()
        checked_grasps = parse_grasps(grasps, self._dims) if grasps else ()
        # a grasp's footprint is a probe's; it holds the tissue at its height: a probe's face
        held = tuple(Probe(g.at, -g.height, g.radius) for g in checked_grasps)
        checked_probes = (*checked_probes, *held)
        load_prints, probe_prints = basis.footprints(checked_loads, checked_probes, self.budget)
        load_forces = [ld.force for ld in checked_loads]

        def advance(tr: Transition) -> Advanced:
            q, v, p1 = self._free_step(state, load_prints, load_forces, tr)
            found = self._contact(
                q, v, checked_probes, probe_prints, load_prints, load_forces, len(held), tr
            )
            return q, v, p1, found

        def rows() -> StepRows:
            grasps = len(held)
            return self._step_rows(load_prints, load_forces, checked_probes, probe_prints, grasps)

        constrained = bool(checked_probes)  # probes and grasps
        q, v, p1, (readings, contact) = self._solve_step(state, advance, constrained, rows)
        done = self._work(p1, contact, q, state.q) if work and self.hold == "zoh" else None
        applied: list[tuple[Any, float]] = [*zip(load_prints, load_forces, strict=True)]
        for fp, reading in zip(probe_prints, readings, strict=True):
            if fp is not None and reading.force != 0.0:
                applied.append((fp, -reading.force))
        _require_finite(q, v, readings)
        q.flags.writeable = v.flags.writeable = p1.flags.writeable = False
        index = state.step + 1
        new = ModalState(index, index * self._dt, q, v, p1, tuple(applied), self._owner)
        probed = len(readings) - len(held)
        grasped = tuple(_grasp_reading(r) for r in readings[probed:])
        return StepResult(new, self.frame(new) if frame else None, readings[:probed], done, grasped)

    def step_loads(
        self,
        states: Sequence[ModalState],
        loads: Sequence[Sequence[Load]],
        frames: Sequence[bool],
    ) -> list[StepResult[ModalState] | LiveError]:
        """Many states' steps under loads alone, as one operation (``interface.BatchedEngine``):
        each result is ``step(states[i], loads[i], frame=frames[i])``, bit for bit (a lone
        ``step`` of loads is this at width one), or the ``LiveError`` that refused it.

        Raises:
            InvalidState: a state from another engine (a bug of the caller's, not input).
        """
        if not self._fixed_transition:
            triples = zip(states, loads, frames, strict=True)
            return [self._refused_or_stepped(s, ld, fr) for s, ld, fr in triples]
        results: list[StepResult[ModalState] | LiveError] = []
        for state, given, frame in zip(states, loads, frames, strict=True):
            try:
                results.append(self._load_step(state, given, frame))
            except LiveError as refused:
                results.append(refused)
        return results

    @property
    def _fixed_transition(self) -> bool:
        """Whether every step takes this core's own transition: an engine whose step solves for
        its end (``_solve_step`` overridden: the nonlinear string) steps its states one by one."""
        return type(self)._solve_step is ModalStepper._solve_step

    def _refused_or_stepped(
        self, state: ModalState, loads: Sequence[Load], frame: bool
    ) -> StepResult[ModalState] | LiveError:
        try:
            return self.step(state, loads, frame=frame)
        except LiveError as refused:
            return refused

    def _load_step(
        self, state: ModalState, loads: Sequence[Load], frame: bool
    ) -> StepResult[ModalState]:
        """A step under loads alone: the free step in one pass over the modes (``free_step``),
        its modal force built in that pass where the basis's forces are outer products."""
        self._check(state)
        basis, kernel = self.basis, self._free_kernel
        checked = parse_loads(loads, self._dims, basis.contains) if loads else ()
        prints = basis.footprints(checked, (), self.budget)[0]
        forces = [ld.force for ld in checked]
        q0, v0, p0 = _flat(state.q), _flat(state.v), _flat(state.load_force)
        factors = [basis.modal_factors(fp) for fp in prints]
        if all(f is not None for f in factors):
            free = kernel.separable(q0, v0, p0, cast(list[tuple[Any, Any]], factors), forces)
        else:
            p1 = self._modal_force(prints, forces).reshape(-1) if prints else None
            free = kernel.given(q0, v0, p0, p1)
        if not math.isfinite(free.total):
            raise InvalidLoad(_NOT_FINITE)
        box = self.modes.box
        q, v, p1 = free.q.reshape(box), free.v.reshape(box), free.p1.reshape(box)
        q.flags.writeable = v.flags.writeable = p1.flags.writeable = False
        index = state.step + 1
        applied = tuple(zip(prints, forces, strict=True))
        new = ModalState(index, index * self._dt, q, v, p1, applied, self._owner)
        return StepResult(new, self.frame(new) if frame else None, (), None)

    def lookahead(
        self, state: ModalState, loads: Sequence[Load] = (), probes: Sequence[Probe] = ()
    ) -> tuple[float, ...]:
        """Each probe's free displacement at the end of the step from ``state`` under
        ``loads`` (``LookaheadEngine``): ``step``'s own free displacement, without the step.

        Raises:
            InvalidLoad, InvalidProbe, InvalidState: as ``step``.
        """
        self._check(state)
        basis = self.basis
        checked_loads = parse_loads(loads, self._dims, basis.contains) if loads else ()
        checked_probes = parse_probes(probes, self._dims) if probes else ()
        load_prints, probe_prints = basis.footprints(checked_loads, checked_probes, self.budget)
        load_forces = [ld.force for ld in checked_loads]

        def advance(tr: Transition) -> Advanced:
            return (*self._free_step(state, load_prints, load_forces, tr), None)

        def rows() -> StepRows:
            return self._step_rows(load_prints, load_forces, (), (), 0)

        q = self._solve_step(state, advance, False, rows)[0]
        from_loads = basis.loads_residual(load_prints, load_forces)
        scale, modal_force = self._scale, basis.modal_force
        return tuple(
            _NAN if fp is None else scale * float(np.vdot(modal_force(fp), q)) + from_loads(fp)
            for fp in probe_prints
        )

    def _step_tools(
        self,
        state: ModalState,
        loads: Sequence[Load],
        tools: Sequence[Tool],
        probes: Sequence[Probe],
        grasps: Sequence[Grasp],
        frame: bool,
        work: bool,
    ) -> StepResult[ModalState]:
        """``step`` with rigid tools (and loads): the tools' points' contact, solved exactly."""
        basis = self.basis
        if probes or grasps:
            raise InvalidTool("a step takes rigid tools, or probes and grasps: not both")
        radius = basis.tool_force_radius
        if radius is None:
            raise InvalidTool("this tissue's tables carry no footprint a tool's point can push")
        checked_loads = parse_loads(loads, self._dims, basis.contains) if loads else ()
        checked_tools = parse_tools(tools, self._dims)
        points = tool_points(
            checked_tools, basis.lattice_coordinates, basis.movable, MAX_TOOL_POINTS
        )
        pushes = [Probe(tuple(float(x) for x in c), 0.0, radius) for c in points.coordinates]
        load_prints, found = basis.footprints(checked_loads, pushes, self.budget, tool_points=True)
        prints = [fp for fp in found if fp is not None]
        if len(prints) != len(found):
            raise AssertionError("a movable lattice point lies outside the basis's domain")
        load_forces = [ld.force for ld in checked_loads]
        applied: list[tuple[Any, float]] = [*zip(load_prints, load_forces, strict=True)]

        def advance(tr: Transition) -> Advanced:
            q, v, p1 = self._free_step(state, load_prints, load_forces, tr)
            return q, v, p1, self._tool_contact(q, v, points, prints, applied, tr)

        q, v, p1, (forces, displacement, pressing) = self._solve_step(state, advance, True)
        done = None
        if work and self.hold == "zoh":
            contact = [(basis.modal_force(fp), f) for fp, f in pressing]
            done = self._work(p1, contact, q, state.q)
        applied += [(fp, -f) for fp, f in pressing]
        readings = tool_readings(checked_tools, points, forces, displacement)
        _require_finite(q, v, ())
        if not all(math.isfinite(r.force) for r in readings):
            raise InvalidTool("this step's contact forces are not finite: its depths are too large")
        q.flags.writeable = v.flags.writeable = p1.flags.writeable = False
        index = state.step + 1
        new = ModalState(index, index * self._dt, q, v, p1, tuple(applied), self._owner)
        return StepResult(new, self.frame(new) if frame else None, (), done, (), readings)

    def _solve_step(
        self,
        state: ModalState,
        advance: Callable[[Transition], Advanced],
        constrained: bool,
        rows: Callable[[], StepRows] | None = None,
    ) -> Advanced:
        """The step's end from ``state``: ``advance`` (the free step and its contact) over
        this core's transition (``constrained``: the step takes probes, grasps or tools). An
        engine whose step depends on its end (the nonlinear string's tension,
        ``live.kirchhoff``) solves for it here, from the step's ``rows`` where given (None:
        a step with tools, whose contact only ``advance`` solves)."""
        return advance(self.transition)

    def _step_rows(
        self,
        load_prints: Sequence[FootprintT],
        load_forces: Sequence[float],
        probes: Sequence[Probe],
        prints: Sequence[FootprintT | None],
        grasps: int,
    ) -> StepRows:
        """The step's ``StepRows`` (the last ``grasps`` probes are grasps), as ``_contact``
        builds its problem."""
        load_force = self._modal_force(load_prints, load_forces)
        rows = [(j, pr, fp) for j, (pr, fp) in enumerate(zip(probes, prints, strict=True)) if fp]
        if not rows:
            return StepRows(load_force, (), (), (), (), (), self._scale)
        basis = self.basis
        footprints = [fp for _, _, fp in rows]
        from_loads = basis.loads_residual(load_prints, load_forces)
        return StepRows(
            load_force=load_force,
            shapes=tuple(basis.modal_force(fp) for fp in footprints),
            depths=tuple(pr.depth for _, pr, _ in rows),
            held=tuple(j >= len(probes) - grasps for j, _, _ in rows),
            offsets=tuple(from_loads(fp) for fp in footprints),
            residual=tuple(tuple(basis.cross(a, b) for b in footprints) for a in footprints),
            scale=self._scale,
        )

    def _free_q(
        self, state: ModalState, p1: FloatArray, loaded: bool, tr: Transition
    ) -> FloatArray:
        """q at the end of a step without contact, the loads' modal force ``p1`` at its end
        (``loaded``: any load; under the first-order hold the previous step's count too)."""
        q = tr.qq * state.q
        q += tr.qv * state.v
        if self.hold == "foh":
            q += tr.foh0_q * state.load_force + tr.foh1_q * p1
        elif loaded:
            q += tr.zoh_q * p1
        return np.asarray(q)

    def _free_step(
        self,
        state: ModalState,
        load_prints: Sequence[FootprintT],
        load_forces: Sequence[float],
        tr: Transition,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q, v at the end of a step without contact, and the loads' modal force then."""
        p1 = self._modal_force(load_prints, load_forces)
        q = self._free_q(state, p1, bool(load_prints), tr)
        v = tr.vq * state.q
        v += tr.vv * state.v
        if self.hold == "foh":
            v += tr.foh0_v * state.load_force + tr.foh1_v * p1
        elif load_prints:
            v += tr.zoh_v * p1
        return q, v, p1

    def _tool_contact(
        self,
        q: FloatArray,
        v: FloatArray,
        points: ToolPoints,
        prints: Sequence[FootprintT],
        loads: Sequence[tuple[Any, float]],
        tr: Transition,
    ) -> tuple[FloatArray, FloatArray, list[tuple[FootprintT, float]]]:
        """Solve the tools' points' contact, apply it to q and v in place; the points' forces
        (>= 0, along -axis), their displacements at the step's end, and the footprints that
        push with their forces."""
        if not points.count:
            return np.zeros(0), np.zeros(0), []
        basis = self.basis
        free = basis.point_frame(points.indices, q, loads)
        compliance = basis.point_compliance(points.indices, prints, tr.zoh_q)
        forces = solve_points(compliance, free - points.surface)
        pressing = [(fp, float(f)) for fp, f in zip(prints, forces, strict=True) if f > 0.0]
        if pressing:
            total = self._modal_force([fp for fp, _ in pressing], [f for _, f in pressing])
            q -= tr.zoh_q * total
            v -= tr.zoh_v * total
        return forces, free - compliance @ forces, pressing

    def frame(self, state: ModalState) -> FloatArray:
        """Displacements on the lattice (x-major, flattened): stepped modes plus correction."""
        self._check(state)
        return self.basis.frame(state.q, state.applied)

    def energy(self, state: ModalState) -> float:
        """Kinetic plus strain energy of the stepped modes: scale / 2 sum (v^2 + w^2 q^2)."""
        self._check(state)
        kinetic = self._scale * 0.5 * float(np.vdot(state.v, state.v))
        return kinetic + float(np.vdot(self._energy_weights, state.q * state.q))

    def describe(self) -> dict[str, object]:
        """The engine's settings and sizes, as plain data (the basis's own beside the core's)."""
        return {
            "engine": self.kind,
            "inputs": sorted(self.inputs),
            **self.subject(),
            "lattice": list(self._lattice),
            "dt": self._dt,
            **self._described_damping(),
            "hold": self.hold,
            "modes_stepped": self.modes.count,
            "mode_box": list(self.modes.box),
            **self.basis.describe(),
            "memory_bytes": self.memory_bytes,
            **self.bounds(),
            "engine_bytes": self.engine_bytes,
            "state_bytes": self.state_bytes,
        }

    def _described_damping(self) -> dict[str, object]:
        if isinstance(self.damping, float):
            return {"damping": self.damping}
        return {
            "damping": "per mode",
            "damping_range": [float(self.damping.min()), float(self.damping.max())],
        }

    def contains(self, at: tuple[float, ...]) -> bool:
        """Whether a centre lies in the basis's domain (``interface.BoundedEngine``)."""
        return self.basis.contains(at)

    def domain_text(self) -> str:
        """The domain's extent in words (the basis's, else the unit interval or square)."""
        described = self.basis.describe()
        lower, upper = described.get("lower"), described.get("upper")
        if not (isinstance(lower, list) and isinstance(upper, list)):
            return " x ".join(["[0, 1]"] * self._dims) + " (problem units)"
        return " x ".join(f"[{a:.6g}, {b:.6g}]" for a, b in zip(lower, upper, strict=True)) + " m"

    def subject(self) -> dict[str, object]:
        """What the engine models, for ``describe`` (an engine over a named problem says so)."""
        return {}

    def bounds(self) -> dict[str, object]:
        """The step budget and the inputs' bounds, as ``describe`` states them."""
        return {
            "max_step_work": self.budget.max_work,
            "max_held_bytes": self.budget.max_held_bytes,
            "max_force": MAX_FORCE,
            "max_depth": MAX_DEPTH,
            "max_radius": MAX_RADIUS,
            "max_shape_value": MAX_SHAPE_VALUE,
            "max_tools": MAX_TOOLS,
            "max_tool_points": MAX_TOOL_POINTS,
            "tool_kinds": list(TOOL_KINDS),
            "tool_force_radius": self.basis.tool_force_radius,
        }

    # -- the parts of a step ----------------------------------------------------------------

    def _work(
        self,
        load_force: FloatArray,
        contact: Sequence[tuple[FloatArray, float]],
        q: FloatArray,
        q0: FloatArray,
    ) -> float:
        """Work on the stepped modes over a held step: scale sum p (q1 - q0), p all forces'."""
        total = load_force.copy()
        for s, force in contact:
            total -= force * s
        return self._scale * float(np.vdot(total, q - q0))

    def _modal_force(self, prints: Sequence[FootprintT], forces: Sequence[float]) -> FloatArray:
        if not prints:
            return self._zeros
        modal_force = self.basis.modal_force
        total = forces[0] * modal_force(prints[0])
        for footprint, force in zip(prints[1:], forces[1:], strict=True):
            total += force * modal_force(footprint)
        return np.asarray(total)

    def _contact(
        self,
        q: FloatArray,
        v: FloatArray,
        probes: Sequence[Probe],
        prints: Sequence[FootprintT | None],
        load_prints: Sequence[FootprintT],
        load_forces: Sequence[float],
        grasps: int,
        tr: Transition,
    ) -> tuple[tuple[ProbeReading, ...], list[tuple[FloatArray, float]]]:
        """Solve contact, apply it to q and v in place; the readings and (s, F) per contact.
        The last ``grasps`` probes are grasps: held exactly, their force of either sign."""
        footprints = [fp for fp in prints if fp is not None]
        if not footprints:
            return tuple(_outside() for _ in probes), []
        basis, scale = self.basis, self._scale
        from_loads = basis.loads_residual(load_prints, load_forces)
        if len(probes) == 1 and not grasps:
            return self._one_probe(q, v, probes[0], footprints[0], from_loads, tr)
        shapes = [basis.modal_force(fp) for fp in footprints]
        gains = [tr.zoh_q * s for s in shapes]  # the end-of-step response to a unit force
        count = len(footprints)
        free = np.empty(count)
        compliance = np.empty((count, count))
        for j, (s, fp) in enumerate(zip(shapes, footprints, strict=True)):
            free[j] = scale * float(np.vdot(s, q)) + from_loads(fp)
            for k in range(j + 1):
                value = scale * float(np.vdot(gains[j], shapes[k])) + basis.cross(fp, footprints[k])
                compliance[j, k] = compliance[k, j] = value
        depths = np.array([pr.depth for pr, fp in zip(probes, prints, strict=True) if fp])
        held = np.array([j >= len(probes) - grasps for j, fp in enumerate(prints) if fp])
        if held.any():
            forces = solve_mixed(compliance, free + depths, held)
        else:
            forces = solve_contact(compliance, free + depths)
        contact = []
        for s, gain, force in zip(shapes, gains, forces, strict=True):
            if force != 0.0:
                q -= force * gain
                v -= (force * tr.zoh_v) * s
                contact.append((s, float(force)))
        displacement = free - compliance @ forces
        statics = [self._static(s, basis.own(fp)) for s, fp in zip(shapes, footprints, strict=True)]
        found = iter(
            _reading(float(f), float(z), float(d), float(compliance[j, j]), statics[j])
            for j, (f, z, d) in enumerate(zip(forces, displacement, depths, strict=True))
        )
        readings = tuple(next(found) if fp else _outside() for fp in prints)
        return readings, contact

    def _one_probe(
        self,
        q: FloatArray,
        v: FloatArray,
        probe: Probe,
        footprint: FootprintT,
        from_loads: Callable[[FootprintT], float],
        tr: Transition,
    ) -> tuple[tuple[ProbeReading, ...], list[tuple[FloatArray, float]]]:
        """``_contact`` for the haptic loop's one probe, in scalars: F = max(0, b / c)."""
        s = self.basis.modal_force(footprint)
        gain = tr.zoh_q * s
        free = self._scale * float(np.vdot(s, q)) + from_loads(footprint)
        own = self.basis.own(footprint)
        compliance = self._scale * float(np.vdot(gain, s)) + own
        static = self._static(s, own)
        force = single_contact(compliance, free + probe.depth)
        if force == 0.0:
            return (_reading(0.0, free, probe.depth, compliance, static),), []
        q -= force * gain
        v -= (force * tr.zoh_v) * s
        reading = _reading(force, free - compliance * force, probe.depth, compliance, static)
        return (reading,), [(s, force)]

    def _static(self, s: FloatArray, own: float) -> float:
        """A footprint's static compliance (displacement per unit force held for ever), from
        its modal force ``s`` and the static correction's own compliance ``own``."""
        return float(np.vdot(self._static_weights, s * s)) + own

    def _project(self, shape: ArrayLike | None, what: str) -> tuple[FloatArray, float]:
        if shape is None:
            return self._zeros, 0.0
        box, residual = self.basis.project(shape, what)
        box.setflags(write=False)
        return box, residual

    def _check(self, state: ModalState) -> None:
        if not isinstance(state, ModalState) or state.owner is not self._owner:
            raise InvalidState("this state was not made by this engine (use its start())")


def positive(value: float, what: str) -> float:
    """``value`` as a finite float > 0, or ``InvalidEngineSettings``."""
    number = float(value)
    if not (math.isfinite(number) and number > 0.0):
        raise InvalidEngineSettings(f"{what} must be a finite number > 0, got {number:.6g}")
    return number


def damping_ratio(value: float) -> float:
    """``value`` as a finite damping ratio >= 0, or ``InvalidEngineSettings``."""
    number = float(value)
    if not (math.isfinite(number) and number >= 0.0):
        raise InvalidEngineSettings(f"damping must be a finite ratio >= 0, got {number:.6g}")
    return number


def damping_ratios(values: ArrayLike, box: tuple[int, ...]) -> FloatArray:
    """Per-mode ratios as a read-only array of the mode box's shape, each finite and >= 0."""
    ratios = np.array(values, dtype=np.float64)
    if ratios.shape != box:
        raise InvalidEngineSettings(f"damping needs one ratio per mode {box}, got {ratios.shape}")
    if not (np.isfinite(ratios).all() and (ratios >= 0.0).all()):
        raise InvalidEngineSettings("damping ratios must be finite and >= 0")
    ratios.setflags(write=False)
    return ratios


_NOT_FINITE = "this step's response is not finite: its forces or depths are too large"


def _flat(array: FloatArray) -> FloatArray:
    """A state's array as one C-contiguous row (a view: a state's arrays are contiguous)."""
    return array.reshape(-1)


def _require_finite(q: FloatArray, v: FloatArray, readings: Sequence[ProbeReading]) -> None:
    """Refuse a step whose response overflowed (inputs within their bounds never do; this is
    the guarantee that no state holds inf or NaN)."""
    # one sum is not finite exactly when some entry is not (or the entries near 1e308)
    if not math.isfinite(float(q.sum()) + float(v.sum())):
        raise InvalidLoad(_NOT_FINITE)
    if not all(math.isfinite(r.force) for r in readings):
        raise InvalidProbe("this step's contact forces are not finite: its depths are too large")


def _reading(
    force: float, displacement: float, depth: float, compliance: float, static: float
) -> ProbeReading:
    gap = 0.0 if force > 0.0 else -(displacement + depth)
    return ProbeReading(force, displacement, gap, compliance, force > 0.0, False, static)


def _outside() -> ProbeReading:
    return ProbeReading(0.0, _NAN, _NAN, _NAN, False, True)


def _grasp_reading(held: ProbeReading) -> GraspReading:
    """A grasp's reading from its probe-like row: its force along +axis (a probe's pushes
    along -axis)."""
    return GraspReading(-held.force + 0.0, held.displacement, held.compliance, held.outside)


def _masked(tr: Transition, kept: NDArray[np.bool_]) -> Transition:
    """The transition with every coefficient 0 off the kept modes (they stay at rest)."""
    arrays = {}
    for name in tr.__dataclass_fields__:
        array = np.where(kept, getattr(tr, name), 0.0)
        array.setflags(write=False)
        arrays[name] = array
    return Transition(**arrays)
