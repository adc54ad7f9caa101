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
by Newton on the free modes (a few vector operations), then the whole step is taken at it; if
its contact moved the string, by the secant method on whole steps from there. Damping ratios
are of the linear frequencies w_n = n pi c.

Every mode the lattice resolves is stepped and there is no static correction: the residual
flexibility of the modes beyond would need the tension too. Units: the problem's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.engine import ModalEngine
from membrane_models.live.errors import InvalidEngineSettings, InvalidLoad
from membrane_models.live.options import damping_option, modes_option, refuse_unknown
from membrane_models.live.stepper import Advanced, ModalState
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
    """The per-mode constants of the theta step's q1(T) = (N0 - T N1) / (D0 + T D1), with
    N0 = from_q q0 + from_v v0 + from_force p and N1 = n1 q0 (``_free_tension``)."""

    from_q: FloatArray
    from_v: FloatArray
    from_force: FloatArray
    n1: FloatArray
    d0: FloatArray
    d1: FloatArray

    @classmethod
    def of(
        cls, theta: float, dt: float, friction: FloatArray, kappa2: FloatArray, kept: FloatArray
    ) -> _Constants:
        d0 = 1.0 + theta * dt * friction
        # N0 = (q0 + (1 - theta) dt v0) D0 + theta dt (v0 (1 - dt f (1 - theta)) + dt p)
        from_v = (1.0 - theta) * dt * d0 + theta * dt * (1.0 - dt * friction * (1.0 - theta))
        return cls(
            from_q=d0 * kept,
            from_v=from_v * kept,
            from_force=theta * dt * dt * kept,
            n1=theta * (1.0 - theta) * dt * dt * kappa2,
            d0=d0,
            d1=theta * theta * dt * dt * kappa2,
        )

    def numerator(self, q0: FloatArray, v0: FloatArray, force: FloatArray) -> FloatArray:
        """N0 of the step from (q0, v0) under a held modal ``force``."""
        return np.asarray(self.from_q * q0 + self.from_v * v0 + self.from_force * force)

    def denominator(self, tension: float) -> FloatArray:
        """D0 + T D1."""
        return np.asarray(self.d0 + tension * self.d1)


class KirchhoffEngine(ModalEngine):
    """The nonlinear string as a live engine (module docstring).

    Args:
        problem: a ``StringKirchhoff`` (its ``c`` and ``stretch`` k are used).
        lattice, dt, damping, modes: as ``ModalEngine``'s (zero-order hold only).

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
        self._kept = kept.astype(np.float64)
        self._constants = {theta: _Constants.of(theta, self.dt, self._friction, self._wavenumber2,
                                                self._kept) for theta in (0.5, 1.0)}  # fmt: skip

    def stretch(self, q: FloatArray) -> float:
        """S = sum (n pi)^2 q_n^2 / 2."""
        return 0.5 * float(np.vdot(self._wavenumber2, q * q))

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

    def _solve_step(
        self, state: ModalState, advance: Callable[[Transition], Advanced], constrained: bool
    ) -> Advanced:
        """The step's tension (module docstring): solved by Newton on the free modes with the
        loads' modal force held (a few vector operations), then the whole step taken at it;
        if its contact moved the string, the secant on the whole step's miss from there."""
        theta = 1.0 if constrained else 0.5
        q0, v0 = state.q, state.v
        s0 = self.stretch(q0)
        rate = float(np.vdot(self._wavenumber2, q0 * v0))  # dS/dt
        guess = self.c2 + self.k * (s0 + theta * self.dt * rate)
        # held: the loads' modal force the last step ended with (its contact's, a grasp's above
        # all, follows the tension too closely to be a better guess: measured, it costs a step)
        tension = self._free_tension(theta, q0, v0, s0, state.load_force, guess)
        found = advance(self._transition(theta, tension))
        miss = self._miss(theta, tension, s0, found[0])
        if abs(miss) <= _TOLERANCE * tension:
            return found
        # then the tension of the free step under the force that step's contact added (held),
        # and from there the secant on whole steps (a grasp's force follows the tension
        # closely, so holding it alone converges slowly)
        c = self._constants[theta]
        gain = c.from_force / c.denominator(tension)  # dq1 / dp of each kept mode
        free = c.numerator(q0, v0, state.load_force) - tension * c.n1 * q0
        free /= c.denominator(tension)
        contact = (found[0] - free) / np.where(self._kept > 0.0, gain, 1.0)
        previous, previous_miss = tension, miss
        tension = self._free_tension(theta, q0, v0, s0, state.load_force + contact, tension)
        for _ in range(_MAX_EVALUATIONS):
            if not (math.isfinite(tension) and tension > 0.0):
                break
            found = advance(self._transition(theta, tension))
            miss = self._miss(theta, tension, s0, found[0])
            if abs(miss) <= _TOLERANCE * tension:
                return found
            slope = (miss - previous_miss) / (tension - previous)
            previous, previous_miss = tension, miss
            tension = tension - miss / slope if slope != 0.0 else tension + miss
        raise InvalidLoad(
            "this step's tension did not converge: its loads or depths stretch the string too far"
        )

    def _free_tension(
        self,
        theta: float,
        q0: FloatArray,
        v0: FloatArray,
        s0: float,
        force: FloatArray,
        guess: float,
    ) -> float:
        """T = c^2 + k ((1 - theta) S0 + theta S1(T)) for the free step under ``force``, by
        Newton on q1(T) = (N0 - T N1) / (D0 + T D1) per mode (``_transition``'s step)."""
        c = self._constants[theta]
        kappa2 = self._wavenumber2
        n0, n1 = c.numerator(q0, v0, force), c.n1 * q0
        tension = guess
        for _ in range(_MAX_EVALUATIONS):
            denominator = c.denominator(tension)
            q1 = (n0 - tension * n1) / denominator
            dq = -(n1 + q1 * c.d1) / denominator
            s1 = 0.5 * float(np.vdot(kappa2, q1 * q1))
            miss = self.c2 + self.k * ((1.0 - theta) * s0 + theta * s1) - tension
            slope = theta * self.k * float(np.vdot(kappa2, q1 * dq)) - 1.0
            change = -miss / slope
            tension += change
            if abs(change) <= _TOLERANCE * tension:
                return tension
        return tension  # the whole step's check decides

    def _miss(self, theta: float, tension: float, s0: float, q1: FloatArray) -> float:
        """c^2 + k ((1 - theta) S0 + theta S1) - T: zero at the step's tension."""
        return self.c2 + self.k * ((1.0 - theta) * s0 + theta * self.stretch(q1)) - tension

    def _transition(self, theta: float, tension: float) -> Transition:
        """The theta step of every kept mode under ``tension`` (module docstring): 1/2 the
        trapezoid, 1 backward Euler."""
        dt, c = self.dt, self._constants[theta]
        gain = self._kept / c.denominator(tension)
        vq = -dt * tension * self._wavenumber2 * gain
        vv = (1.0 - dt * self._friction * (1.0 - theta) - tension * c.n1) * gain
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
