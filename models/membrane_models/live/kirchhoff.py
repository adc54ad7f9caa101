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
Given T_bar the step is linear, so loads, probes, grasps and tools are the stepping core's
(``stepper.ModalStepper``, contact exact at the step's end); the one unknown scalar T_bar is
solved by the secant method on T_bar = c^2 + k (S0 + S1(T_bar)) / 2, each evaluation a whole
linear step with its contact. Damping ratios are of the linear frequencies w_n = n pi c.

Every mode the lattice resolves is stepped and there is no static correction: the residual
flexibility of the modes beyond would need the tension too. Units: the problem's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.engine import ModalEngine
from membrane_models.live.errors import InvalidEngineSettings, InvalidLoad
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
        self._inertia = 2.0 / self.dt**2 + self._friction / self.dt

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
            "integrator": "energy-conserving trapezoidal step under the step's mean tension",
            "static_correction": False,
        }

    def _solve_step(self, state: ModalState, advance: Callable[[Transition], Advanced]) -> Advanced:
        """The mean tension (module docstring): solved by Newton on the free modes with the
        contact's modal force held (cheap: a few vector operations), then the whole step taken
        at it; again, with the contact that step found, until the tension is the step's."""
        q0, v0 = state.q, state.v
        s0 = self.stretch(q0)
        # the loads' modal force the last step ended with (its contact's, a grasp's above all,
        # follows the tension too closely to be a better guess: measured, it costs a step)
        held = state.load_force
        tension = self.c2 + self.k * (s0 + 0.5 * self.dt * float(np.vdot(self._wavenumber2,
                                                                         q0 * v0)))  # fmt: skip
        tension = self._free_tension(q0, v0, s0, held, tension)
        found = advance(self._trapezoid(tension))
        miss = self._miss(tension, s0, found[0])
        if abs(miss) <= _TOLERANCE * tension:
            return found
        # then the tension the free step balances with the force that step's contact added,
        # and from there the secant on the whole step's miss (a grasp's force follows the
        # tension closely, so holding it alone converges slowly)
        free = self._free_modes(q0, v0, self._zeros, tension)
        held = (found[0] - free) / self._trapezoid_gain(tension)
        previous, previous_miss = tension, miss
        tension = self._free_tension(q0, v0, s0, held, tension)
        for _ in range(_MAX_EVALUATIONS):
            if not (math.isfinite(tension) and tension > 0.0):
                break
            found = advance(self._trapezoid(tension))
            miss = self._miss(tension, s0, found[0])
            if abs(miss) <= _TOLERANCE * tension:
                return found
            slope = (miss - previous_miss) / (tension - previous)
            previous, previous_miss = tension, miss
            tension = tension - miss / slope if slope != 0.0 else tension + miss
        raise InvalidLoad(
            "this step's tension did not converge: its loads or depths stretch the string too far"
        )

    def _free_modes(
        self, q0: FloatArray, v0: FloatArray, force: FloatArray, tension: float
    ) -> FloatArray:
        """q1 of the trapezoidal step under ``tension`` and a held modal ``force``."""
        half = 0.5 * tension * self._wavenumber2
        numerator = (self._inertia - half) * q0 + (2.0 / self.dt) * v0 + force
        return np.asarray(numerator / (self._inertia + half) * self._kept)

    def _trapezoid_gain(self, tension: float) -> FloatArray:
        return np.asarray(1.0 / (self._inertia + 0.5 * tension * self._wavenumber2))

    def _free_tension(
        self, q0: FloatArray, v0: FloatArray, s0: float, force: FloatArray, guess: float
    ) -> float:
        """T with T = c^2 + k (S0 + S1(T)) / 2 for the free step under ``force``: Newton."""
        rhs = self._inertia * q0 + (2.0 / self.dt) * v0 + force
        bent = self._wavenumber2 * q0
        tension = guess
        for _ in range(_MAX_EVALUATIONS):
            denominator = self._inertia + 0.5 * tension * self._wavenumber2
            q1 = (rhs - 0.5 * tension * bent) / denominator * self._kept
            dq = -0.5 * (bent + self._wavenumber2 * q1) / denominator
            s1 = 0.5 * float(np.vdot(self._wavenumber2, q1 * q1))
            miss = self.c2 + 0.5 * self.k * (s0 + s1) - tension
            slope = 0.5 * self.k * float(np.vdot(self._wavenumber2, q1 * dq)) - 1.0
            change = -miss / slope
            tension += change
            if abs(change) <= _TOLERANCE * tension:
                return tension
        return tension  # the whole step's check decides

    def _miss(self, tension: float, s0: float, q1: FloatArray) -> float:
        """c^2 + k (S0 + S1) / 2 - T_bar: zero at the step's tension."""
        return self.c2 + 0.5 * self.k * (s0 + self.stretch(q1)) - tension

    def _trapezoid(self, tension: float) -> Transition:
        """The trapezoidal step of every kept mode under ``tension`` (module docstring)."""
        dt = self.dt
        stiffness = tension * self._wavenumber2
        zoh_q = self._kept / (self._inertia + 0.5 * stiffness)
        qq = (self._inertia - 0.5 * stiffness) * zoh_q
        qv = (2.0 / dt) * zoh_q
        zeros = self._zeros
        return Transition(
            qq=qq,
            qv=qv,
            vq=(2.0 / dt) * (qq - self._kept),
            vv=(2.0 / dt) * qv - self._kept,
            zoh_q=zoh_q,
            zoh_v=(2.0 / dt) * zoh_q,
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
    unknown = sorted(set(options) - set(KIRCHHOFF_OPTIONS))
    if unknown:
        known = ", ".join(KIRCHHOFF_OPTIONS)
        raise InvalidEngineSettings(f"unknown [live] option {unknown[0]!r:.40}; known: {known}")
    damping = options.get("damping", 0.0)
    if isinstance(damping, bool) or not isinstance(damping, int | float):
        raise InvalidEngineSettings("[live] damping must be a number")
    if not (math.isfinite(damping) and 0.0 <= damping < 1.0):
        raise InvalidEngineSettings(f"[live] damping must be in [0, 1), got {damping:.6g}")
    modes = options.get("modes")
    if modes is not None and (
        isinstance(modes, bool) or not isinstance(modes, int) or not 1 <= modes <= _MAX_MODES
    ):
        raise InvalidEngineSettings(f"[live] modes must be an integer from 1 to {_MAX_MODES}")
    if len(lattice) != 1:
        raise InvalidEngineSettings("a string's lattice has one axis")
    return KirchhoffEngine(problem, int(lattice[0]), dt, damping=float(damping), modes=modes)
