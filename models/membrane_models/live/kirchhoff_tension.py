"""The nonlinear string's step tension: one scalar equation, solved by Newton with its contact.

Under a tension T the theta step of every sine mode is linear (``live.kirchhoff``):

    q1(T) = m / D(T) - alpha q0 - g(T) P,   D = d0 + T d1,   g = theta dt^2 / D,

with P = sum_j F_j s_j the contact's modal force over the step, F the rows' forces (probes
pushing, grasps holding; ``stepper.StepRows``). The step's tension solves

    f(T) = c^2 + k ((1 - theta) S0 + theta S1(T)) - T = 0,   S1 = sum kappa^2 q1^2 / 2.

Given T, F is the rows' contact problem on the one-step compliance C = scale S g S^T + R and
violation b = scale S q_free + offsets + depths (``live.contact``: the core's own problem, so a
whole step at the T found here ends with the same forces). Newton needs dS1/dT: with the
active rows A fixed, u = q1 + alpha q0 and w = u d1 / D,

    dq1/dT = -w - g sum_A dF_j s_j,   dF_A = -C_AA^-1 scale S_A w,

(the contact's force follows the string: what the secant on whole steps had to find out, one
whole step at a time). The iterates stay at or above c^2 + k (1 - theta) S0, T's least (S1 >= 0,
k >= 0): just after an impact the guess from the start's rates can be wild (measured: -336 for
a root at 115). Every evaluation is a few vector operations over the modes and scalars, so the
solve costs a fraction of one whole step. Units: the problem's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from membrane_models.live.contact import single_contact, solve_contact, solve_mixed
from membrane_models.live.errors import InvalidGrasp, InvalidProbe
from membrane_models.live.stepper import StepRows

__all__ = ["ContactRows", "tension_newton"]

FloatArray = NDArray[np.float64]

# the relative change after which Newton stops: the error left, about K dT^2 / T with K measured
# up to 0.024 (with contact; 1e-6 without), is under 3e-14 of T, below the whole step's
# tolerance (1e-12, ``live.kirchhoff``), which decides
SETTLED = 1e-6
MAX_NEWTON = 40


@dataclass(frozen=True)
class ContactRows:
    """A step's contact rows (``stepper.StepRows``) over the string's flat mode vector, with
    the theta step's input gain g D = theta dt^2 on the kept modes (``from_force``)."""

    shapes: FloatArray  # (rows, modes)
    depths: FloatArray
    held: NDArray[np.bool_]
    offsets: FloatArray
    residual: FloatArray
    scale: float
    from_force: FloatArray

    @classmethod
    def of(cls, rows: StepRows, from_force: FloatArray) -> ContactRows:
        return cls(
            shapes=np.array([s.reshape(-1) for s in rows.shapes]),
            depths=np.array(rows.depths),
            held=np.array(rows.held, dtype=bool),
            offsets=np.array(rows.offsets),
            residual=np.array(rows.residual),
            scale=rows.scale,
            from_force=from_force.reshape(-1),
        )

    def forces(
        self, q_free: FloatArray, gain: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """The rows' forces F at the step's end from ``q_free`` under the gain 1 / D, with
        g s_j per row and C; None where the contact problem has no answer (a row that cannot
        move: the whole step refuses it with its own error)."""
        shaped = self.shapes * (self.from_force * gain)  # g s_j
        try:
            if self.depths.size == 1:  # the haptic loop's one row, in scalars
                c = self.scale * float(np.dot(shaped[0], self.shapes[0])) + self.residual[0, 0]
                b = self.scale * float(np.dot(self.shapes[0], q_free)) + self.offsets[0]
                b += self.depths[0]
                compliance = np.array([[c]])
                if self.held[0]:
                    if not c > 0.0:
                        return None
                    force = np.array([b / c])
                else:
                    force = np.array([single_contact(c, b)])
                return force, shaped, compliance
            compliance = self.scale * (shaped @ self.shapes.T) + self.residual
            violation = self.scale * (self.shapes @ q_free) + self.offsets + self.depths
            if self.held.any():
                force = solve_mixed(compliance, violation, self.held)
            else:
                force = solve_contact(compliance, violation)
        except (InvalidProbe, InvalidGrasp):
            return None
        return force, shaped, compliance

    def force_rate(self, force: FloatArray, compliance: FloatArray, w: FloatArray) -> FloatArray:
        """dF/dT on the active rows (held, or pushing), 0 elsewhere, with w = u d1 / D
        (module docstring)."""
        if force.size == 1:  # active: the caller's force is not 0
            return np.array([-self.scale * float(np.dot(self.shapes[0], w)) / compliance[0, 0]])
        active = self.held | (force > 0.0)
        rate = np.zeros(force.size)
        if active.any():
            pushed = -self.scale * (self.shapes[active] @ w)
            rate[active] = np.linalg.solve(compliance[np.ix_(active, active)], pushed)
        return rate


def tension_newton(
    *,
    c2: float,
    k: float,
    kappa2: FloatArray,
    theta: float,
    d0: FloatArray,
    d1: FloatArray,
    kept: FloatArray,
    m: FloatArray,
    alpha_q0: FloatArray | None,
    s0: float,
    contact: ContactRows | None,
    guess: float,
) -> float:
    """The step's tension T (module docstring) by Newton from ``guess``, until a change under
    ``SETTLED`` of T (then the next is rounding) or non-finite; the whole step's check decides
    whether it is solved.

    Args:
        c2, k: the string's c^2 and stretch k (tension c^2 + k S).
        kappa2: (n pi)^2 per mode (0 off the kept modes); theta: 1/2 or 1.
        d0, d1, kept: D = d0 + T d1 per mode; the kept modes' mask (1.0 or 0.0).
        m, alpha_q0: q1 = m / D - alpha q0 without contact (None: alpha = 0).
        s0: the start's stretch; contact: the step's rows (None: none).
    """
    floor = c2 + k * (1.0 - theta) * s0  # T >= floor: S1 >= 0 and k >= 0
    tension = max(guess, floor)
    for _ in range(MAX_NEWTON):
        gain = kept / (d0 + tension * d1)
        u = m * gain
        q1 = u if alpha_q0 is None else u - alpha_q0
        solved = None if contact is None else contact.forces(q1, gain)
        if solved is not None and solved[0].any():
            force, shaped, compliance = solved
            push = force @ shaped
            q1 = q1 - push
            u = u - push
        kq = kappa2 * q1
        w = u * d1
        w *= gain  # -dq1/dT with the contact's force held
        rate = -float(np.dot(kq, w))  # dS1/dT so
        if solved is not None and solved[0].any():
            force_rate = contact.force_rate(force, compliance, w)  # type: ignore[union-attr]
            rate -= float(force_rate @ (shaped @ kq))  # 0 on the rows not active
        miss = c2 + k * ((1.0 - theta) * s0 + theta * 0.5 * float(np.dot(kq, q1))) - tension
        change = miss / (1.0 - theta * k * rate)
        tension = max(tension + change, floor)  # a wild guess's first change may undershoot
        if not math.isfinite(tension) or abs(change) <= SETTLED * tension:
            break
    return tension
