"""From a requested simulation time to the step the scene serves: snapping and policy.

All arithmetic is float64 on the requested time itself (no float32 anywhere), so that t = 1e9 or
t = -1e-12 give the right step (or the right out-of-domain answer).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Literal, NamedTuple

from membrane_client.protocol import Domain
from membrane_errors import UserError

__all__ = ["OutOfDomain", "Sample", "Timeline"]

# How many float64 epsilons (relative to the magnitudes involved) count as "on a step".
_SNAP_EPSILONS = 8


class OutOfDomain(UserError):
    """A time outside the scene's domain under the ``error`` policy."""


class Sample(NamedTuple):
    """What to serve for one requested time (a tuple: one is made per query).

    Attributes:
        step: Step index k (under linear snapping, the step at or before the time).
        t: Simulation time served (the step time, or the requested time when interpolating).
        weight: Weight of step k + 1 in a linear interpolation (0 means frame k alone).
        domain: Inside the domain, or clamped/held by the policy.
    """

    step: int
    t: float
    weight: float
    domain: Domain


@dataclass(frozen=True)
class Timeline:
    """A scene's time grid: steps 0 .. last_step at start_offset + k * dt.

    Model time (what evaluators take) is k * dt; simulation time adds ``start_offset``.
    """

    dt: float
    last_step: int
    start_offset: float = 0.0
    snapping: Literal["nearest", "linear"] = "nearest"
    policy: Literal["error", "clamp", "hold"] = "hold"

    def step_time(self, step: int) -> float:
        """Simulation time of step k."""
        return self.start_offset + step * self.dt

    def model_time(self, step: int) -> float:
        """Model time of step k (the network's t)."""
        return step * self.dt

    def resolve(self, t: float) -> Sample:
        """The sample served for simulation time ``t`` (finite).

        Raises:
            OutOfDomain: ``t`` is outside the domain and the policy is ``error``.
            ValueError: ``t`` is NaN or infinite.
        """
        if not math.isfinite(t):
            raise ValueError(f"t must be a finite number of seconds, got {t}")
        position = (t - self.start_offset) / self.dt  # in steps, float64
        if not math.isfinite(position):  # |t| near the float64 limit: overflows to +-inf steps
            return self._outside(t, before=position < 0.0)
        position = self._snap_to_step(position, t)
        if self.snapping == "nearest":
            step = math.floor(position + 0.5)  # round half up: one rule for every tie
            if 0 <= step <= self.last_step:
                return Sample(step, self.step_time(step), 0.0, Domain.INSIDE)
        elif 0.0 <= position <= self.last_step:
            step = min(math.floor(position), self.last_step)
            weight = position - step if step < self.last_step else 0.0
            return Sample(step, t, weight, Domain.INSIDE)
        return self._outside(t, before=position < 0.0)

    def _snap_to_step(self, position: float, t: float) -> float:
        """``position`` made a whole step when it is within rounding of one.

        A step's time as a client computes it, start_offset + k * dt, carries a rounding, and so
        do the subtraction and the division above: the scene's own last step time may come out
        a few ulps past N (or before k), which must not make it out of the domain.
        """
        nearest = round(position)
        scale = (abs(t) + abs(self.start_offset)) / self.dt + abs(position)
        on_step = abs(position - nearest) <= _SNAP_EPSILONS * sys.float_info.epsilon * scale
        return float(nearest) if on_step else position

    def _outside(self, t: float, before: bool) -> Sample:
        if self.policy == "error":
            start, end = self.start_offset, self.step_time(self.last_step)
            raise OutOfDomain(
                f"t = {t!r} s is outside the scene's time domain [{start!r}, {end!r}] s "
                "(policy 'error')"
            )
        step = 0 if before else self.last_step
        domain = Domain.CLAMPED if self.policy == "clamp" else Domain.HELD
        return Sample(step, self.step_time(step), 0.0, domain)
