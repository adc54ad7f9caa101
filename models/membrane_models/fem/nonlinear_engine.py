"""The ``fem-nonlinear`` engine kind: the von Karman plate, reduced, stepped live under tools.

The tissue's plate reduced to its lowest modes with the in-plane field condensed
(``reduced_plate``: internal forces cubic in the modal coordinates, exact for deflections in
the modes' span), stepped by the energy-consistent scheme with Newton and the tools' contact
inside it (``reduced_dynamics``), what the modes do not carry kept as the linear static
residual under the tools' point forces. The reduced plate is built once per tissue, lattice,
mode count and in-plane condition and cached beside the linear engine's tables
(``reduced_cache``).

The basis follows the tools (``basis_follower``): each tool's contact-adapted vector, the
static response to a unit point force at its centre rounded to ``ADAPT_SPACING``, is added to
the modes once built off the step's thread (``adapted_basis``), and a state moves onto it by
the mass-orthogonal projection (``adapted_basis.carried``). A sphere pressed to 2 h takes the
full plate's force within about 1 % with it, 4-5 % low without (docs/NONLINEAR.md).

Units: SI, as the ``fem`` engine's: a tool's centre, radius and depth in m (depth > 0 presses
along -z), its force in N (>= 0, the tissue pushed along -z), frames in m. It takes rigid tools
and initial shapes; loads, probes and grasps are refused (``inputs``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.fem.adapted_basis import Adaptation, AdaptedPlate, carried
from membrane_models.fem.assembly import ElementName, assemble
from membrane_models.fem.basis_follower import BasisFollower
from membrane_models.fem.geometry import Domain
from membrane_models.fem.inside import inside_boundary
from membrane_models.fem.models import Plate
from membrane_models.fem.nonlinear import INPLANE
from membrane_models.fem.reduced_cache import cached_reduced_plate
from membrane_models.fem.reduced_dynamics import (
    IterationMatrix,
    NotConverged,
    StepCoefficients,
    step_reduced,
)
from membrane_models.fem.reduced_kernel import compiled_chord
from membrane_models.fem.reduced_plate import ReducedPlate
from membrane_models.fem.tissue import Tissue
from membrane_models.live.errors import InvalidEngineSettings, InvalidState, InvalidTool
from membrane_models.live.inputs import MAX_TOOL_POINTS, MAX_TOOLS, parse_tools
from membrane_models.live.interface import (
    TOOL_KINDS,
    Grasp,
    Load,
    Probe,
    Start,
    StepResult,
    Tool,
)
from membrane_models.live.options import modes_option, refuse_unknown
from membrane_models.live.projection import checked_shape
from membrane_models.live.stepper import positive
from membrane_models.live.tools import ToolPoints, tool_points, tool_readings

__all__ = [
    "ADAPTED_BUILDS",
    "ADAPT_SPACING",
    "DEFAULT_MODES",
    "NONLINEAR_OPTIONS",
    "NonlinearPlateEngine",
    "NonlinearPlateState",
    "build_nonlinear_engine",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
DEFAULT_MODES = 20
# Deeper than this many thicknesses the rotations are no longer moderate (slopes near 1 on the
# skin patch at 4 h): the von Karman plate is not the tissue's model there.
_DEPTH_PER_THICKNESS = 4.0
_MAX_MODES = 40  # G has r^4 entries: 40 modes hold 20 MB and cost about 1 ms a Newton iteration
_STATE_OVERHEAD = 2048
# The grid a tool's adapted vector is put on (m): a vector 0.25 mm from a sphere's centre costs
# its press at 2 h 0.1-0.5 % of the full plate's force, 1 mm up to 1.9 % (measured on the skin
# patch, docs/NONLINEAR.md).
ADAPT_SPACING = 0.25e-3
_ADAPTED_KEPT = 8  # adapted bases kept built (about 6 MB each at 20 modes on the skin patch)
ADAPTED_BUILDS = ("beside", "wait")

NONLINEAR_OPTIONS = {
    "modes": f"the plate's lowest modes reduced to (default {DEFAULT_MODES}, at most {_MAX_MODES})",
    "inplane": 'the edges\' in-plane condition: "held" (default), "sliding" or "free"',
    "adapted": "add each tool's static response at its centre to the basis (default true)",
    "adapted_build": (
        'how a step meets a tool vector not built yet: "beside" (default: on the basis it has, '
        'the vector built in a worker meanwhile) or "wait" (for its build: forces that depend on '
        "the inputs alone)"
    ),
}


@dataclass(frozen=True)
class NonlinearPlateState:
    """The reduced plate's state: immutable, so a refused or retried step leaves it as it was.

    Attributes:
        step, time: steps taken and step * dt (s).
        q, v: the reduced coordinates and their rates.
        points, forces: the lattice points under the last step's tools and their forces (N),
            whose static residual the frame adds.
        adapted: the basis q and v are on: the modes and the tools' adapted vectors (None:
            the modes alone), with its step's ``coefficients``.
    """

    step: int
    time: float
    q: FloatArray
    v: FloatArray
    points: IntArray
    forces: FloatArray
    owner: object = field(default=None, repr=False, compare=False)
    matrix: IterationMatrix | None = field(default=None, repr=False, compare=False)
    acceleration: FloatArray | None = field(default=None, repr=False, compare=False)
    adapted: AdaptedPlate | None = field(default=None, repr=False, compare=False)
    coefficients: StepCoefficients | None = field(default=None, repr=False, compare=False)


class NonlinearPlateEngine:
    """The reduced von Karman plate as a live engine (module docstring)."""

    kind = "fem-nonlinear"

    def __init__(
        self,
        tissue: Tissue,
        lattice: tuple[int, int],
        dt: float,
        *,
        modes: int = DEFAULT_MODES,
        inplane: str = "held",
        plate: ReducedPlate | None = None,
        adapted: bool = True,
        adapted_build: str = "beside",
        compiled: bool | None = None,
    ) -> None:
        if not isinstance(tissue.model, Plate):
            raise InvalidEngineSettings("the fem-nonlinear engine steps a plate, not a membrane")
        if adapted_build not in ADAPTED_BUILDS:
            raise InvalidEngineSettings(
                f"[live] adapted_build must be one of {', '.join(ADAPTED_BUILDS)}"
            )
        self.tissue = tissue
        self._dt = positive(dt, "dt")
        self.inplane = inplane
        self.plate = (
            plate if plate is not None else cached_reduced_plate(tissue, lattice, modes, inplane)
        )
        self.damping = tissue.damping_ratios(self.plate.omega)
        self.coefficients = StepCoefficients.of(self.plate, self._dt, self.damping)
        self.max_depth = _DEPTH_PER_THICKNESS * tissue.model.thickness
        self._coordinates = self.plate.coordinates
        self._owner = object()
        movable = self.plate.shapes[self.plate.movable]
        self._inverse = np.linalg.pinv(movable)
        self._zeros = np.zeros(self.plate.size)
        self._zeros.setflags(write=False)
        self._no_points = np.zeros(0, dtype=np.intp)
        self._no_points.setflags(write=False)
        self._last_tool: tuple[tuple[object, ...], ToolPoints] | None = None
        self._chord = compiled_chord() if compiled is None or compiled else None
        self.follower = (
            BasisFollower(
                functools.partial(
                    _adaptation, _parts(tissue.domain), _model(tissue), self.plate, inplane
                ),
                ADAPT_SPACING,
                _ADAPTED_KEPT,
                wait=adapted_build == "wait",
            )
            if adapted
            else None
        )

    # -- the interface ----------------------------------------------------------------------

    @property
    def spatial_dims(self) -> int:
        return 2

    @property
    def lattice_shape(self) -> tuple[int, ...]:
        return self.plate.lattice

    @property
    def dt(self) -> float:
        return self._dt

    @property
    def inputs(self) -> frozenset[str]:
        """Rigid tools and initial shapes."""
        return frozenset({"tools", "initial"})

    @property
    def engine_bytes(self) -> int:
        """The reduced plate's arrays (the quartic, the shapes, the residual and the vectors),
        and as many again for each adapted basis kept (one tool's: r + 1 vectors, the quartic
        twice with its packed forms)."""
        p = self.plate
        own = p.quartic.nbytes + p.shapes.nbytes + p.residual.nbytes + self._inverse.nbytes
        if self.follower is None:
            return int(own + p.vectors.nbytes)
        n = p.size + 1
        adapted = 8 * (2 * n**4 + (n * (n + 1) // 2) ** 2 + p.residual.size
                       + (p.shapes.shape[0] + 2 * p.vectors.shape[0]) * n)  # fmt: skip
        return int(own + p.vectors.nbytes + self.follower.capacity * adapted)

    @property
    def state_bytes(self) -> int:
        """q, v and the acceleration, the forces of at most every tool's points with their
        indices, and the iteration matrix (the LU, the points' shapes, response, compliance and
        flexibility, and the last active set's solution, at most (2 p, p), with its key)."""
        r, points = self.plate.size + MAX_TOOLS, MAX_TOOLS * MAX_TOOL_POINTS
        kept = 2 * r * points + 4 * points * points + 2 * points  # shapes ... the set's key
        matrix = 8 * (r * r + r + kept)
        coefficients = 2 * 8 * r
        return 3 * 8 * r + 16 * points + matrix + coefficients + _STATE_OVERHEAD

    def describe(self) -> dict[str, object]:
        p = self.plate
        return {
            "engine": self.kind,
            "inputs": sorted(self.inputs),
            "tissue": self.tissue.name,
            "model": "von Karman plate, reduced: the lowest modes, the in-plane field condensed",
            "inplane": self.inplane,
            "lattice": list(p.lattice),
            "dt": self._dt,
            "damping": self.damping if isinstance(self.damping, float) else "per mode",
            "modes": p.modes,
            "reduced_size": p.size,
            "adapted": self._adapted_text(),
            "frequency_range_hz": [float(w / (2 * math.pi)) for w in (p.omega[0], p.omega[-1])],
            "integrator": "energy-consistent discrete gradient, Newton in the reduced space",
            "units": "SI",
            "lower": list(p.lower),
            "upper": list(p.upper),
            "max_depth": self.max_depth,
            "max_tools": MAX_TOOLS,
            "max_tool_points": MAX_TOOL_POINTS,
            "tool_kinds": list(TOOL_KINDS),
            "memory_bytes": self.engine_bytes,
            "engine_bytes": self.engine_bytes,
            "state_bytes": self.state_bytes,
        }

    def contains(self, at: tuple[float, ...]) -> bool:
        """Whether a centre lies on the plate (``interface.BoundedEngine``)."""
        point = np.array([at[:2]], dtype=np.float64)
        extent = max(b - a for a, b in zip(self.plate.lower, self.plate.upper, strict=True))
        return bool(inside_boundary(point, self.plate.boundary, 1e-12 * extent)[0])

    def domain_text(self) -> str:
        lower, upper = self.plate.lower, self.plate.upper
        return " x ".join(f"[{a:.6g}, {b:.6g}]" for a, b in zip(lower, upper, strict=True)) + " m"

    def start(
        self, displacement: ArrayLike | None = None, velocity: ArrayLike | None = None
    ) -> Start[NonlinearPlateState]:
        """The state at t = 0, at rest or from shapes on the lattice (least squares on the
        points the plate can move at).

        Raises:
            InvalidShape: a shape of the wrong size, or with NaN or inf.
        """
        self.prepare()  # a session is about to press: ready its first basis (if not yet)
        q, q_residual = self._project(displacement, "displacement")
        v, v_residual = self._project(velocity, "velocity")
        state = NonlinearPlateState(0, 0.0, q, v, self._no_points, np.zeros(0), self._owner)
        return Start(state, q_residual, v_residual)

    def step(
        self,
        state: NonlinearPlateState,
        loads: Sequence[Load] = (),
        probes: Sequence[Probe] = (),
        *,
        frame: bool = True,
        grasps: Sequence[Grasp] = (),
        tools: Sequence[Tool] = (),
    ) -> StepResult[NonlinearPlateState]:
        """One step with rigid ``tools`` pressing (none: the plate rings freely).

        Raises:
            InvalidTool: a bad tool, one deeper than ``max_depth``, or a step Newton cannot
                solve; ``state`` is unchanged (it always is).
            InvalidState: a state from another engine.
        """
        self._check(state)
        if loads or probes or grasps:  # the server refuses them first (``inputs``)
            raise InvalidTool("the fem-nonlinear engine takes rigid tools only")
        checked = parse_tools(tools, 2) if tools else ()
        for index, tool in enumerate(checked):
            if tool.depth > self.max_depth:
                raise InvalidTool(
                    f"tool {index}: depth {tool.depth:.6g} m is past {self.max_depth:.6g} m "
                    f"({_DEPTH_PER_THICKNESS:g} thicknesses), where the rotations are no longer "
                    "moderate"
                )
        points = self._points(checked)
        same = points.indices is state.points or np.array_equal(points.indices, state.points)
        start = state.forces > 0.0 if same and state.forces.size else None
        begun = self._basis_for(state, checked)
        try:
            solved = step_reduced(begun.plate, begun.coefficients, begun.q, begun.v,
                                  points.indices, points.surface, start=start,
                                  matrix=begun.matrix, acceleration=begun.acceleration,
                                  chord=self._chord)  # fmt: skip
        except NotConverged:
            raise InvalidTool(
                "this step's contact could not be solved: the tools moved too far in one step"
            ) from None
        q, v = solved.q, solved.v
        q.flags.writeable = v.flags.writeable = False
        index = state.step + 1
        acceleration = (v - begun.v) / self._dt
        acceleration.flags.writeable = False
        new = NonlinearPlateState(index, index * self._dt, q, v, points.indices, solved.forces,
                                  self._owner, solved.matrix, acceleration, begun.adapted,
                                  begun.coefficients)  # fmt: skip
        readings = tool_readings(checked, points, solved.forces, solved.displacement)
        return StepResult(new, self.frame(new) if frame else None, (), None, (), readings)

    @property
    def step_waits(self) -> str | None:
        """Why a step may wait (``live.WaitingEngine``): with ``adapted_build="wait"``, for a
        tool vector's build."""
        if self.follower is None or not self.follower.waits:
            return None
        return 'adapted_build = "wait": a step waits for its tool vector\'s build (seconds)'

    @property
    def compiled(self) -> bool:
        """Whether steps that keep the last matrix and contact set are taken by the compiled
        chord iteration (``reduced_kernel``; default: where numba is installed)."""
        return self._chord is not None

    def frame(self, state: NonlinearPlateState) -> FloatArray:
        """Displacements on the lattice (x-major, flattened), m: the reduced plate plus the
        residual under the tools' forces."""
        self._check(state)
        plate = self._plate(state)
        values = plate.shapes @ state.q
        if state.forces.size:
            values -= plate.residual[:, state.points] @ state.forces
        return np.asarray(values)

    def energy(self, state: NonlinearPlateState) -> float:
        """Kinetic, bending and stretching energy of the reduced plate (J)."""
        self._check(state)
        plate, q, v = self._plate(state), state.q, state.v
        bending = 0.5 * float(np.sum(plate.omega**2 * q * q))
        return 0.5 * float(v @ v) + bending + plate.stretching_energy(q)

    def prepare(self) -> None:
        """Start the adapted bases' worker and what its builds need (seconds of a core, in
        that process: ``PreparingEngine``), so that the first session's press waits for no
        more than its vector's build; nothing when it is under way or done, or without them."""
        if self.follower is not None:
            self.follower.prepare()

    def close(self) -> None:
        """Stop the adapted bases' worker thread (a build under way is finished first)."""
        if self.follower is not None:
            self.follower.close()

    # -- helpers ----------------------------------------------------------------------------

    def _plate(self, state: NonlinearPlateState) -> ReducedPlate:
        return self.plate if state.adapted is None else state.adapted.plate

    def _basis_for(self, state: NonlinearPlateState, tools: Sequence[Tool]) -> _Begun:
        """The basis this step is taken on and the state on it: the state's own, or the one
        the tools' places call for once it is built (the state carried over by projection)."""
        adapted = state.adapted
        if self.follower is not None:
            adapted = self.follower.follow(state.adapted, [tool.at for tool in tools])
        if adapted is state.adapted:
            plate = self._plate(state)
            coefficients = state.coefficients or self.coefficients
            return _Begun(plate, coefficients, adapted, state.q, state.v, state.matrix,
                          state.acceleration)  # fmt: skip
        assert adapted is not None
        source = state.adapted if state.adapted is not None else self.plate
        damping = self.tissue.damping_ratios(adapted.plate.omega)
        coefficients = StepCoefficients.of(adapted.plate, self._dt, damping)
        acceleration = state.acceleration
        if acceleration is not None:
            acceleration = carried(acceleration, source, adapted)
        return _Begun(adapted.plate, coefficients, adapted, carried(state.q, source, adapted),
                      carried(state.v, source, adapted), None, acceleration)  # fmt: skip

    def _adapted_text(self) -> dict[str, object] | None:
        if self.follower is None:
            return None
        return {
            "vectors": "each tool's static response to a unit force at its centre",
            "spacing": ADAPT_SPACING,
            "kept": self.follower.capacity,
            "build": "wait" if self.follower.waits else "beside",
        }

    def _points(self, tools: Sequence[Tool]) -> ToolPoints:
        """The lattice points under ``tools``. One tool's are kept from the last step where
        only its depth changed (a press): its surface moves down by the depth, whatever its
        kind (``live.tools.tool_surface``)."""
        if len(tools) != 1:
            return tool_points(tools, self._coordinates, self.plate.movable, MAX_TOOL_POINTS)
        tool = tools[0]
        key = (tool.kind, tool.at, tool.radius)
        if self._last_tool is None or self._last_tool[0] != key:
            level = Tool(tool.kind, tool.at, 0.0, tool.radius)
            at_rest = tool_points([level], self._coordinates, self.plate.movable,
                                  MAX_TOOL_POINTS)  # fmt: skip
            self._last_tool = (key, at_rest)
        at_rest = self._last_tool[1]
        # the same index array every step of a press: ``step`` knows the points by identity
        return ToolPoints(at_rest.indices, at_rest.coordinates, at_rest.surface - tool.depth,
                          at_rest.owner)  # fmt: skip

    def _project(self, shape: ArrayLike | None, what: str) -> tuple[FloatArray, float]:
        if shape is None:
            return self._zeros, 0.0
        values = checked_shape(shape, self.plate.lattice, what)
        q = self._inverse @ values[self.plate.movable]
        q.setflags(write=False)
        norm = float(np.linalg.norm(values))
        if norm == 0.0:
            return q, 0.0
        return q, float(np.linalg.norm(values - self.plate.shapes @ q)) / norm

    def _check(self, state: NonlinearPlateState) -> None:
        if not isinstance(state, NonlinearPlateState) or state.owner is not self._owner:
            raise InvalidState("this state was not made by this engine (use its start())")


def _adaptation(
    domain: tuple[Any, dict[str, Any], dict[str, Any]],
    tissue: tuple[Plate, Any, ElementName | None],
    plate: ReducedPlate,
    inplane: str,
) -> Adaptation:
    """What ``plate``'s adapted bases are built from, in the follower's worker process: the
    domain as its mesh, parts and curves (its read-only maps do not pickle), the tissue as its
    model, supports and element."""
    model, supports, element = tissue
    system = assemble(Domain(*domain), model, supports, element)
    return Adaptation.of(system, plate, inplane)


def _parts(domain: Domain) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    return domain.mesh, dict(domain.parts), dict(domain.curves)


def _model(tissue: Tissue) -> tuple[Plate, Any, ElementName | None]:
    assert isinstance(tissue.model, Plate)
    return tissue.model, tissue.supports, tissue.element


@dataclass(frozen=True)
class _Begun:
    """A step's start on the basis it is taken on."""

    plate: ReducedPlate
    coefficients: StepCoefficients
    adapted: AdaptedPlate | None
    q: FloatArray
    v: FloatArray
    matrix: IterationMatrix | None
    acceleration: FloatArray | None


def build_nonlinear_engine(
    problem: object, lattice: tuple[int, ...], dt: float, options: Mapping[str, object]
) -> NonlinearPlateEngine:
    """The fem-nonlinear engine of a plate tissue scene.

    Raises:
        InvalidEngineSettings: not a plate tissue, a lattice not 2-D, or a bad option.
    """
    if not isinstance(problem, Tissue):
        raise InvalidEngineSettings(
            "the fem-nonlinear engine steps a physical tissue: give the scene a [tissue] table"
        )
    refuse_unknown(options, NONLINEAR_OPTIONS)
    modes = modes_option(options, _MAX_MODES, DEFAULT_MODES)
    assert modes is not None
    inplane = options.get("inplane", "held")
    if inplane not in INPLANE:
        raise InvalidEngineSettings(f"[live] inplane must be one of {', '.join(INPLANE)}")
    if len(lattice) != 2:
        raise InvalidEngineSettings("a tissue's lattice needs nx and ny")
    adapted = options.get("adapted", True)
    if not isinstance(adapted, bool):
        raise InvalidEngineSettings("[live] adapted must be true or false")
    build = options.get("adapted_build", "beside")  # the engine checks it
    return NonlinearPlateEngine(problem, (int(lattice[0]), int(lattice[1])), dt, modes=modes,
                                inplane=str(inplane), adapted=adapted,
                                adapted_build=str(build))  # fmt: skip
