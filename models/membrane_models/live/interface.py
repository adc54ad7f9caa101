"""What every live engine offers: state in, loads and probes in; state, frame and probes out.

A live engine is stateful in the physics but not in the object: ``step`` takes a state and
returns a new one, leaving the old one valid. A server can therefore keep the last reply and
answer a retried step without applying it twice, and a refused step (bad input) leaves nothing
half done. The exact modal engine (``engine.ModalEngine``) implements this; FEM modes or a
learned Koopman model (encode once, step K, decode) fit the same shape.

Sign and units: problem units of the engine's problem. A load's ``force`` > 0 pushes the tissue
along +axis (the sign of f in the problem's equation); a probe presses along -axis, and its
reported contact force is >= 0 (the tissue is pushed along -axis, the tool feels it along
+axis). Footprints are Gaussian, normalised over the line or the plane (see ``footprint``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Generic, Literal, Protocol, TypeVar, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.live.errors import LiveError

__all__ = [
    "ENGINE_INPUTS",
    "TOOL_KINDS",
    "BatchedEngine",
    "BoundedEngine",
    "Grasp",
    "GraspReading",
    "Hold",
    "LiveEngine",
    "Load",
    "LookaheadEngine",
    "PreparingEngine",
    "Probe",
    "ProbeReading",
    "Start",
    "StepResult",
    "Tool",
    "ToolReading",
    "WaitingEngine",
]

FloatArray = NDArray[np.float64]
Hold = Literal["zoh", "foh"]
# What a live engine may take: loads, probes, grasps and tools per step, initial shapes at open.
ENGINE_INPUTS = frozenset({"loads", "probes", "grasps", "tools", "initial"})
# A rigid tool's shape: a sphere (a ball tip; a circle across a string) or a flat-ended
# cylinder (a punch; a flat segment on a string), its axis along the displacement axis.
TOOL_KINDS = ("sphere", "cylinder")
StateT = TypeVar("StateT")


@dataclass(frozen=True)
class Load:
    """A Gaussian pressure of total force ``force`` centred at ``at``.

    Membrane: F / (pi r^2) exp(-rho^2 / r^2); string: F / (sqrt(pi) r) exp(-x^2 / r^2), r = 0 a
    point force (string only). The part of the Gaussian beyond the clamped edges acts on the
    support, not on the tissue.
    """

    at: tuple[float, ...]
    force: float
    radius: float


@dataclass(frozen=True)
class Probe:
    """A rigid tip whose face is ``depth`` below the rest surface, pressing along -axis: signed,
    so that a tip held above the rest surface (depth < 0) meets tissue that rings up to it.

    Its footprint is a load's Gaussian of radius ``radius`` (> 0 on a membrane). A centre
    outside the domain touches nothing.
    """

    at: tuple[float, ...]
    depth: float
    radius: float


@dataclass(frozen=True)
class ProbeReading:
    """What a probe measured at the end of a step.

    Attributes:
        force: contact force F >= 0 (pushes the tissue along -axis).
        displacement: z-bar, the footprint-weighted displacement at the end of the step.
        gap: -(z-bar + depth) >= 0; 0 in contact.
        compliance: c, the one-step compliance under the tip (displacement per unit force).
        in_contact: F > 0.
        outside: the centre is outside the domain: nothing touched, the rest NaN.
        static_compliance: the static compliance under the tip (displacement per unit force
            held until the tissue settles): 1 / the tissue's stiffness there, which a haptic
            coupling is scaled to.
    """

    force: float
    displacement: float
    gap: float
    compliance: float
    in_contact: bool
    outside: bool = False
    static_compliance: float = math.nan


@dataclass(frozen=True)
class Grasp:
    """A hold on the tissue: its footprint-weighted displacement kept at ``height`` (signed,
    along +axis: > 0 lifts skin or pulls a rope up) by whatever force that takes, of either
    sign. Its footprint is a probe's; a centre outside the domain holds nothing.
    """

    at: tuple[float, ...]
    height: float
    radius: float


@dataclass(frozen=True)
class GraspReading:
    """What a grasp needed at the end of a step.

    Attributes:
        force: the force it applies to the tissue, along +axis (> 0 lifts; the hand feels -F).
        displacement: z-bar, the footprint-weighted displacement: the grasp's height.
        compliance: c, the one-step compliance under it (displacement per unit force).
        outside: the centre is outside the domain: nothing held, the rest NaN.
    """

    force: float
    displacement: float
    compliance: float
    outside: bool = False


@dataclass(frozen=True)
class Tool:
    """A rigid tool pressing along -axis, whose lowest point is ``depth`` below the rest surface
    (signed: < 0 holds it above) over the centre ``at``.

    Its surface over a point at distance rho from the centre is ``-depth + R - sqrt(R^2 -
    rho^2)`` for a sphere of radius R, and ``-depth`` for a cylinder of radius R, for rho <= R.
    The tissue is kept at or below that surface at every lattice point under the tool (the
    points a frame shows), each carrying its contact force as the basis's tool footprint
    (``describe``'s ``tool_force_radius``). A tool that covers no lattice point touches nothing.
    """

    kind: str
    at: tuple[float, ...]
    depth: float
    radius: float


@dataclass(frozen=True)
class ToolReading:
    """What a rigid tool measured at the end of a step.

    Attributes:
        force: the total contact force >= 0 (pushes the tissue along -axis; the tool feels it
            along +axis).
        centre: where that force acts (its force-weighted centre; the tool's centre when 0).
        contacts: lattice points in contact (force > 0).
        points: lattice points under the tool (its constraint points).
        gap: the smallest distance between the tool's surface and the tissue over its points
            (0 in contact; NaN without points).
        penetration: the largest depth of tissue above the tool's surface over its points (0
            up to rounding: the contact is solved exactly; NaN without points).
    """

    force: float
    centre: tuple[float, ...]
    contacts: int
    points: int
    gap: float
    penetration: float


@dataclass(frozen=True)
class StepResult(Generic[StateT]):
    """One step's answer.

    Attributes:
        state: the state at the end of the step.
        frame: displacements on the lattice (x-major, flattened), or None when not asked.
        probes: one reading per probe, in the order given.
        work: work done on the kept modes by loads and probes over the step (zero-order hold;
            None under first-order hold).
        grasps: one reading per grasp, in the order given (engines without grasps: none).
        tools: one reading per tool, in the order given (engines without tools: none).
    """

    state: StateT
    frame: FloatArray | None
    probes: tuple[ProbeReading, ...]
    work: float | None
    grasps: tuple[GraspReading, ...] = ()
    tools: tuple[ToolReading, ...] = ()


@dataclass(frozen=True)
class Start(Generic[StateT]):
    """An initial state and how well the modes carry the shapes asked for.

    Attributes:
        state: the state at t = 0.
        displacement_residual, velocity_residual: ||given - projected|| / ||given|| on the
            lattice (0 for a zero shape).
    """

    state: StateT
    displacement_residual: float
    velocity_residual: float


@runtime_checkable
class BoundedEngine(Protocol):
    """An engine that can say whether a centre lies in its domain (a step's ``strict`` check)."""

    def contains(self, at: tuple[float, ...]) -> bool:
        """Whether ``at`` lies in the domain (closed)."""

    def domain_text(self) -> str:
        """The domain's extent in words, for a refusal (e.g. "[0, 0.05] x [0, 0.05] m")."""


@runtime_checkable
class LookaheadEngine(Protocol):
    """An engine that can give each probe's free displacement at the end of the next step
    without taking it (a haptic loop renders that step's contact from it)."""

    def lookahead(
        self, state: Any, loads: Sequence[Load] = (), probes: Sequence[Probe] = ()
    ) -> tuple[float, ...]:
        """Per probe, the footprint-weighted displacement at the end of the step from ``state``
        under ``loads`` and no contact (NaN for a probe outside the domain)."""


@runtime_checkable
class PreparingEngine(Protocol):
    """An engine with work to start before its first session (a worker process, tables): a
    server calls ``prepare`` once the scene is served, so that no session waits for it."""

    def prepare(self) -> None:
        """Start that work, off the caller's thread; returns at once."""


@runtime_checkable
class WaitingEngine(Protocol):
    """An engine whose step may wait for work off its thread (seconds): fine stepped in one
    process, not in a server, where the waiting step would hold every client's requests."""

    @property
    def step_waits(self) -> str | None:
        """Why a step may wait, in a few words (None: it never does)."""


@runtime_checkable
class BatchedEngine(Protocol):
    """An engine that steps many sessions' states under loads alone as one operation (the
    server's batched steps): each result is the step ``step`` takes from that state with those
    loads, bit for bit, whatever the batch's width."""

    def step_loads(
        self,
        states: Sequence[Any],
        loads: Sequence[Sequence[Load]],
        frames: Sequence[bool],
    ) -> list[StepResult[Any] | LiveError]:
        """Per state, its step under its loads (and its frame where asked), or the error that
        refused that one (bad input: the others are stepped all the same)."""


class LiveEngine(Protocol[StateT]):
    """A stateful engine beside the film evaluators (see the module docstring)."""

    @property
    def spatial_dims(self) -> int:
        """1 (string) or 2 (membrane)."""

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        """Points per axis of the frames (x-major)."""

    @property
    def dt(self) -> float:
        """The step, in problem time units."""

    @property
    def inputs(self) -> frozenset[str]:
        """What a step or an open takes: some of ``ENGINE_INPUTS`` ("loads", "probes",
        "initial"); the server refuses the others before they reach the engine."""

    @property
    def state_bytes(self) -> int:
        """The most one state of this engine holds, whatever it is stepped with."""

    def describe(self) -> dict[str, object]:
        """What ``describe``'s ``live`` map says of the engine: its kind, settings and bounds
        (plain data: numbers, strings, lists)."""

    def start(
        self, displacement: ArrayLike | None = None, velocity: ArrayLike | None = None
    ) -> Start[StateT]:
        """The state at t = 0: at rest, or from shapes given on the lattice."""

    def step(
        self,
        state: StateT,
        loads: Sequence[Load] = (),
        probes: Sequence[Probe] = (),
        *,
        frame: bool = True,
    ) -> StepResult[StateT]:
        """Advance one step under ``loads`` and ``probes`` (the server converts a step's wire
        maps into these, through the client's live schema); bad input raises a ``LiveError``."""

    def frame(self, state: StateT) -> FloatArray:
        """The displacements of ``state`` on the lattice (x-major, flattened)."""
