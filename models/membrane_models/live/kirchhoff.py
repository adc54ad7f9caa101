"""The Kirchhoff-Carrier string live: tension that grows with stretch, stepped in sine modes.

    u_tt = (c^2 + k S) u_xx + f,   S = int_0^1 u_x^2 dx = sum (n pi)^2 q_n^2 / 2

(``exact.kirchhoff_carrier``). In the sine modes the string is the linear one with one scalar
changed: each mode sees the tension T = c^2 + k S. The step is the energy-conserving
discretisation of that structure, a trapezoidal step of every mode under the step's mean
tension

    (q1 - q0) / dt = (v0 + v1) / 2,
    (v1 - v0) / dt = -2 zeta w_n (v0 + v1) / 2 - T_bar (n pi)^2 (q0 + q1) / 2 + p_n,
    T_bar = c^2 + k (S0 + S1) / 2,

which conserves E = sum v_n^2 / 4 + c^2 S / 2 + k S^2 / 4 exactly without damping or input
(T_bar (S1 - S0) is the potential's change), is second order and unconditionally stable.
A step that takes probes, grasps or tools is backward Euler instead (theta = 1, T = c^2 + k S1):
held at a point, the trapezoid's end velocity 2 (q1 - q0) / dt - v0 = -v0 flips sign every
step with nothing to damp it (its mean is 0), and a held probe's force rang for ever (measured:
0 to 0.64 at one depth after 6 s); backward Euler is L-stable, brings a held point to rest and
keeps the static force exact, at a numerical damping ratio of about w dt / 2 while it presses
(0.2 % of the fundamental at the scene's dt). Contact is inelastic.
Given T the step is linear, so loads, probes, grasps and tools are the stepping core's
(``stepper.ModalStepper``, contact exact at the step's end). The one unknown scalar T is solved
first, by Newton on the step's modes with its loads and its probes' and grasps' contact
(``kirchhoff_tension``: each row's force follows T in the derivative), then the whole step is
taken at it, once. A tool's contact, which only the whole step solves, may still move the
string off that T: then the secant method on whole steps from there. With numba installed, a
step with at most one probe or grasp is solved by one compiled loop of the same arithmetic
(``kirchhoff_kernel``), and a step under loads alone is taken whole in one compiled call (the
tension, then the core's free step by its own expressions: its general path's bits). Damping
ratios are of the linear frequencies w_n = n pi c.

Every mode the lattice resolves is stepped and there is no static correction: the residual
flexibility of the modes beyond would need the tension too. Units: the problem's.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.engine import ModalEngine
from membrane_models.live.errors import InvalidEngineSettings, InvalidLoad
from membrane_models.live.inputs import parse_loads
from membrane_models.live.interface import Grasp, Load, Probe, StepResult, Tool
from membrane_models.live.kirchhoff_kernel import (
    COEFFICIENTS,
    CONSTANT_ROWS,
    PARAMETERS,
    compiled_theta_step,
)
from membrane_models.live.kirchhoff_tension import MAX_NEWTON, SETTLED, ContactRows, tension_newton
from membrane_models.live.options import damping_option, modes_option, refuse_unknown
from membrane_models.live.stepper import Advanced, ModalState, StepRows
from membrane_models.live.transition import Transition
from membrane_models.problems import Problem, StringKirchhoff

__all__ = ["KIRCHHOFF_OPTIONS", "KirchhoffEngine", "build_kirchhoff_engine"]

FloatArray = NDArray[np.float64]
_TOLERANCE = 1e-12  # relative: |T_bar - (c^2 + k (S0 + S1) / 2)| at which a step is solved
_MAX_EVALUATIONS = 40
_MAX_MODES = 4096

KIRCHHOFF_OPTIONS = {
    "damping": "modal damping ratio of the linear frequencies, in [0, 1) (default 0)",
    "modes": "modes to step (default: those the lattice resolves, points - 2)",
}


@dataclass(frozen=True)
class _Constants:
    """The per-mode constants of the theta step under a tension T, 0 off the kept modes.

    With D = d0 + T d1 (d0 = 1 + theta dt f, d1 = theta^2 dt^2 kappa^2, f = 2 zeta w) and
    alpha = (1 - theta) / theta, the step's end is

        q1(T) = m / D - alpha q0,   m = from_q q0 + from_v v0 + from_force p,

    p the modal force held over the step; its transition (``KirchhoffEngine._transition``)
    is vq = -dt T kappa^2 / D, vv = (relaxed - T n1) / D, qq = 1 + theta dt vq,
    qv = (1 - theta) dt + theta dt vv, zoh_v = dt / D, zoh_q = theta dt zoh_v, with
    relaxed = 1 - dt f (1 - theta) and n1 = theta (1 - theta) dt^2 kappa^2.
    """

    theta: float
    alpha: float
    from_q: FloatArray
    from_v: FloatArray
    from_force: FloatArray
    d0: FloatArray
    d1: FloatArray
    relaxed: FloatArray
    n1: FloatArray

    @classmethod
    def of(
        cls, theta: float, dt: float, friction: FloatArray, kappa2: FloatArray, kept: FloatArray
    ) -> _Constants:
        alpha = (1.0 - theta) / theta
        d0 = 1.0 + theta * dt * friction
        # the step's own numerator N0 = (q0 + (1 - theta) dt v0) D0 + theta dt (v0 (1 - dt f
        # (1 - theta)) + dt p), less T theta (1 - theta) dt^2 kappa^2 q0 = T alpha d1 q0: with
        # T d1 = D - d0 that is m - alpha D q0, m = N0 + alpha d0 q0
        relaxed = 1.0 - dt * friction * (1.0 - theta)
        from_v = (1.0 - theta) * dt * d0 + theta * dt * relaxed
        return cls(
            theta=theta,
            alpha=alpha,
            from_q=d0 / theta * kept,
            from_v=from_v * kept,
            from_force=theta * dt * dt * kept,
            d0=d0,
            d1=theta * theta * dt * dt * kappa2,
            relaxed=relaxed,
            n1=theta * (1.0 - theta) * dt * dt * kappa2,
        )

    def numerator(self, q0: FloatArray, v0: FloatArray, force: FloatArray | None) -> FloatArray:
        """m of the step from (q0, v0) under a held modal ``force`` (None: none)."""
        m = self.from_q * q0
        m += self.from_v * v0
        if force is not None:
            m += self.from_force * force
        return np.asarray(m)


@dataclass(frozen=True)
class _Start:
    """What a step's tension solve needs of its start: q0, v0, alpha q0 (None: alpha = 0), S0
    and the guess of the step's tension from the path's Taylor series (no contact)."""

    q0: FloatArray
    v0: FloatArray
    alpha_q0: FloatArray | None
    s0: float
    guess: float


class _Scratch(threading.local):
    """Per thread and theta, the compiled kernels' workspace (``kirchhoff_kernel``: the rows
    they write a step's transition to, then the constants) and the ``Transition`` over its
    first rows: read by that step's ``advance`` alone (its results are new arrays), so each
    step of a thread may write them again."""

    def __init__(self, packed: dict[float, FloatArray], zeros: FloatArray) -> None:
        self.workspaces = {theta: self._workspace(c, zeros) for theta, c in packed.items()}

    @staticmethod
    def _workspace(constants: FloatArray, zeros: FloatArray) -> tuple[FloatArray, Transition]:
        work = np.zeros((COEFFICIENTS + constants.shape[0], constants.shape[1]))
        work[COEFFICIENTS:] = constants
        qq, qv, vq, vv, zoh_q, zoh_v = (work[j, : zeros.size] for j in range(COEFFICIENTS))
        return work, Transition(qq, qv, vq, vv, zoh_q, zoh_v, zeros, zeros, zeros, zeros)


class KirchhoffEngine(ModalEngine):
    """The nonlinear string as a live engine (module docstring).

    Args:
        problem: a ``StringKirchhoff`` (its ``c`` and ``stretch`` k are used).
        lattice, dt, damping, modes: as ``ModalEngine``'s (zero-order hold only).
        compiled: step by the compiled kernel (``kirchhoff_kernel``; default: when numba is
            installed); False takes the numpy path (the reference the kernel is tested
            against).

    Raises:
        InvalidEngineSettings: a setting out of range.
    """

    def __init__(
        self,
        problem: StringKirchhoff,
        lattice: int,
        dt: float,
        *,
        damping: float = 0.0,
        modes: int | None = None,
        compiled: bool | None = None,
    ) -> None:
        super().__init__(problem, lattice, dt, damping=damping, modes=modes,
                         step_limit=None, static_correction=False)  # fmt: skip
        self.kind = "kirchhoff"
        self.c2 = float(problem.c) ** 2
        self.k = float(problem.stretch)
        omega = self.modes.omega
        kept = self.modes.kept
        self._wavenumber2 = np.where(kept, (omega / float(problem.c)) ** 2, 0.0)
        self._friction = np.where(kept, 2.0 * np.asarray(self.damping) * omega, 0.0)
        self._damped = bool(self._friction.any())
        self._kept = kept.astype(np.float64)
        self._constants = {theta: _Constants.of(theta, self.dt, self._friction, self._wavenumber2,
                                                self._kept) for theta in (0.5, 1.0)}  # fmt: skip
        self._kernels = compiled_theta_step() if compiled is None or compiled else None
        packed = {theta: self._pack(c) for theta, c in self._constants.items()}
        self._scratch = _Scratch(packed, self._zeros)

    @property
    def compiled(self) -> bool:
        """Whether its steps are solved by the compiled kernels (``kirchhoff_kernel``)."""
        return self._kernels is not None

    def stretch(self, q: FloatArray) -> float:
        """S = sum (n pi)^2 q_n^2 / 2."""
        return 0.5 * float(np.dot(self._wavenumber2 * q, q))

    def tension(self, state: ModalState) -> float:
        """c^2 + k S at ``state``."""
        self._check(state)
        return self.c2 + self.k * self.stretch(state.q)

    def energy(self, state: ModalState) -> float:
        """sum v^2 / 4 + c^2 S / 2 + k S^2 / 4: conserved without damping or input."""
        self._check(state)
        s = self.stretch(state.q)
        return 0.25 * float(np.vdot(state.v, state.v)) + 0.5 * self.c2 * s + 0.25 * self.k * s * s

    def subject(self) -> dict[str, object]:
        return {
            "problem": self.problem.name,
            "c": math.sqrt(self.c2),
            "stretch": self.k,
            "integrator": "energy-conserving trapezoidal step under the step's mean tension; "
            "backward Euler in steps with probes, grasps or tools",
            "static_correction": False,
        }

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
        """``ModalStepper.step``; a step under loads alone, where the kernels are compiled, in
        one call that solves the tension and takes the free step (the core's expressions: the
        same bits as its general path, ``tests/models/live/test_live_kirchhoff.py``)."""
        if probes or grasps or tools or work or self._kernels is None:
            return super().step(state, loads, probes, frame=frame, work=work, grasps=grasps,
                                tools=tools)  # fmt: skip
        self._check(state)
        basis = self.basis
        checked = parse_loads(loads, self._dims, basis.contains) if loads else ()
        prints = basis.footprints(checked, (), self.budget)[0]
        forces = [ld.force for ld in checked]
        p1 = self._modal_force(prints, forces)
        work_rows, _ = self._scratch.workspaces[0.5]
        loaded = p1 is not self._zeros
        tension, miss, q, v = self._kernels[3](state.q, state.v, loaded, p1, work_rows)
        finite = math.isfinite(float(q.sum()) + float(v.sum()))
        if not (finite and abs(miss) <= _TOLERANCE * tension):  # the general path refuses it
            return super().step(state, loads, frame=frame)  # or solves it by the secant
        q.flags.writeable = v.flags.writeable = p1.flags.writeable = False
        index = state.step + 1
        applied = tuple(zip(prints, forces, strict=True))
        new = ModalState(index, index * self.dt, q, v, p1, applied, self._owner)
        return StepResult(new, self.frame(new) if frame else None, (), None)

    def _solve_step(
        self,
        state: ModalState,
        advance: Callable[[Transition], Advanced],
        constrained: bool,
        rows: Callable[[], StepRows] | None = None,
    ) -> Advanced:
        """The step's tension (module docstring): solved by Newton on the step's modes with
        its loads and contact rows (scalars and a few vector operations, or one compiled loop),
        then the whole step taken at it; if that missed (a tool's contact, which only the whole
        step solves, or a contact whose rows changed on the way), the secant on whole steps."""
        c = self._constants[1.0 if constrained else 0.5]
        inputs = rows() if rows is not None else None
        force = state.load_force if inputs is None else inputs.load_force
        held = None if force is self._zeros else force
        kernels = self._kernels
        if kernels is not None and (inputs is None or len(inputs.depths) <= 1):
            work, transition = self._scratch.workspaces[c.theta]
            if inputs is not None and inputs.depths:
                row = (float(inputs.held[0]), inputs.depths[0], inputs.offsets[0],
                       inputs.residual[0][0], inputs.scale)  # fmt: skip
                tension, s0, miss = kernels[2](state.q, state.v, force, work, inputs.shapes[0],
                                               np.array(row))  # fmt: skip
            elif held is not None:
                tension, s0, miss = kernels[1](state.q, state.v, force, work)
            else:
                tension, s0, miss = kernels[0](state.q, state.v, work)
            found = advance(transition)
            if inputs is None or inputs.depths:  # the whole step's contact decides
                miss = self._miss(c, tension, s0, found[0])
        else:
            start = self._start(c, state, held)
            tension, s0 = self._tension(c, start, held, inputs), start.s0
            found = advance(self._transition(c, tension))
            miss = self._miss(c, tension, s0, found[0])
        if abs(miss) <= _TOLERANCE * tension:
            return found
        return self._secant(c, self._start(c, state, held), force, tension, miss, found, advance)

    def _pack(self, c: _Constants) -> FloatArray:
        """The kernels' per-theta constants: ``kirchhoff_kernel.CONSTANT_ROWS`` and a last row
        that starts with the scalars (``PARAMETERS``)."""
        arrays = {"kappa2": self._wavenumber2, "kept": self._kept, "friction": self._friction}
        rows = [arrays[name] if name in arrays else getattr(c, name) for name in CONSTANT_ROWS]
        scalars = {"c2": self.c2, "k": self.k, "theta": c.theta, "alpha": c.alpha, "dt": self.dt,
                   "settled": SETTLED, "max_newton": float(MAX_NEWTON)}  # fmt: skip
        packed = np.zeros((len(rows) + 1, max(self._kept.size, len(PARAMETERS))))
        packed[: len(rows), : self._kept.size] = rows
        packed[len(rows), : len(PARAMETERS)] = [scalars[name] for name in PARAMETERS]
        return _read_only(packed)

    def _start(self, c: _Constants, state: ModalState, force: FloatArray | None) -> _Start:
        """The start's stretch and the guess T ~ c^2 + k (S0 + theta (dt S' + dt^2 S'' / 2))
        (the mean stretch over the trapezoid, the end's for backward Euler), S' and S'' from
        the free modes: q'' = p - f q' - T0 kappa^2 q."""
        q0, v0, kappa2 = state.q, state.v, self._wavenumber2
        kq = kappa2 * q0
        s0 = 0.5 * float(np.dot(kq, q0))
        rate = float(np.dot(kq, v0))
        tension0 = self.c2 + self.k * s0
        second = float(np.dot(kappa2 * v0, v0)) - tension0 * float(np.dot(kq, kq))
        if force is not None:
            second += float(np.dot(kq, force))
        if self._damped:
            second -= float(np.dot(kq, self._friction * v0))
        dt = self.dt
        guess = self.c2 + self.k * (s0 + c.theta * dt * (rate + 0.5 * dt * second))
        alpha_q0 = c.alpha * q0 if c.alpha else None
        return _Start(q0, v0, alpha_q0, s0, guess)

    def _tension(
        self,
        c: _Constants,
        start: _Start,
        force: FloatArray | None,
        rows: StepRows | None,
        guess: float | None = None,
    ) -> float:
        """T = c^2 + k ((1 - theta) S0 + theta S1(T)) by Newton, S1 of q1(T) = m / D - alpha q0
        (``_Constants``) less the rows' contact (``tension_newton``); ``guess`` else the
        start's."""
        return tension_newton(
            c2=self.c2,
            k=self.k,
            kappa2=self._wavenumber2,
            theta=c.theta,
            d0=c.d0,
            d1=c.d1,
            kept=self._kept,
            m=c.numerator(start.q0, start.v0, force),
            alpha_q0=start.alpha_q0,
            s0=start.s0,
            contact=None if rows is None or not rows.depths else ContactRows.of(rows, c.from_force),
            guess=start.guess if guess is None else guess,
        )

    def _secant(
        self,
        c: _Constants,
        start: _Start,
        force: FloatArray,
        tension: float,
        miss: float,
        found: Advanced,
        advance: Callable[[Transition], Advanced],
    ) -> Advanced:
        """The secant on whole steps from a whole step at ``tension`` that missed: first the
        tension with the force that step's contact added held, then the secant (a grasp's force
        follows the tension closely, so holding it alone converges slowly)."""
        gain = c.from_force / (c.d0 + tension * c.d1)  # dq1 / dp of each kept mode
        m = c.numerator(start.q0, start.v0, force)
        free = m * self._kept / (c.d0 + tension * c.d1)
        if start.alpha_q0 is not None:
            free -= start.alpha_q0
        contact = (found[0] - free) / np.where(self._kept > 0.0, gain, 1.0)
        previous, previous_miss = tension, miss
        tension = self._tension(c, start, force + contact, None, guess=tension)
        for _ in range(_MAX_EVALUATIONS):
            if not (math.isfinite(tension) and tension > 0.0):
                break
            found = advance(self._transition(c, tension))
            miss = self._miss(c, tension, start.s0, found[0])
            if abs(miss) <= _TOLERANCE * tension:
                return found
            slope = (miss - previous_miss) / (tension - previous)
            previous, previous_miss = tension, miss
            tension = tension - miss / slope if slope != 0.0 else tension + miss
        raise InvalidLoad(
            "this step's tension did not converge: its loads or depths stretch the string too far"
        )

    def _miss(self, c: _Constants, tension: float, s0: float, q1: FloatArray) -> float:
        """c^2 + k ((1 - theta) S0 + theta S1) - T: zero at the step's tension."""
        theta = c.theta
        return self.c2 + self.k * ((1.0 - theta) * s0 + theta * self.stretch(q1)) - tension

    def _transition(self, c: _Constants, tension: float) -> Transition:
        """The theta step of every kept mode under ``tension`` (module docstring): 1/2 the
        trapezoid, 1 backward Euler (``_Constants``; written as the energy's figure was
        measured with: the same coefficients in another arrangement round differently, and
        one measured a spread of 3.2e-14 for 1.4e-14 over 10^4 steps)."""
        dt, theta = self.dt, c.theta
        gain = self._kept / (c.d0 + tension * c.d1)
        vq = -dt * tension * self._wavenumber2 * gain
        vv = (c.relaxed - tension * c.n1) * gain
        zoh_v = dt * gain
        zeros = self._zeros
        return Transition(
            qq=self._kept + theta * dt * vq,
            qv=((1.0 - theta) * dt) * self._kept + theta * dt * vv,
            vq=vq,
            vv=vv,
            zoh_q=theta * dt * zoh_v,
            zoh_v=zoh_v,
            foh0_q=zeros,
            foh0_v=zeros,
            foh1_q=zeros,
            foh1_v=zeros,
        )


def _read_only(array: FloatArray) -> FloatArray:
    array.setflags(write=False)
    return array


def build_kirchhoff_engine(
    problem: Problem | object, lattice: tuple[int, ...], dt: float, options: Mapping[str, object]
) -> KirchhoffEngine:
    """The nonlinear string's live engine for a ``string-kirchhoff`` scene.

    Raises:
        InvalidEngineSettings: not that problem, or an unknown or bad option.
    """
    if not isinstance(problem, StringKirchhoff):
        raise InvalidEngineSettings(
            'the kirchhoff engine steps the string-kirchhoff problem (model = "string-kirchhoff")'
        )
    refuse_unknown(options, KIRCHHOFF_OPTIONS)
    damping = damping_option(options)
    modes = modes_option(options, _MAX_MODES, None)
    if len(lattice) != 1:
        raise InvalidEngineSettings("a string's lattice has one axis")
    return KirchhoffEngine(problem, int(lattice[0]), dt, damping=damping, modes=modes)
