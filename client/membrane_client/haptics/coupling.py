"""The virtual coupling: a spring-damper between the device and a massless tool proxy, the
proxy pressing the tissue through the contact the last server step sent.

Along the press axis, depths are positive into the tissue (a probe's ``depth``: the tip's
lowest point ``depth`` below the rest surface). The last step's contact (``Contact``) gives the
tissue's force on a tip held at depth p over that step: F(p) = max(0, (z + p) / c), z the
tissue's free displacement under the tip (along +axis, without the contact) and c its one-step
compliance. The coupling holds the proxy where its spring-damper balances that force,

    k (x - p) + B ((x - x_prev) - (p - p_prev)) / T = F(p),

x the device's depth, T the loop's period, the damper on the relative velocity by backward
differences (implicit in p, so stable at any stiffness). The left side falls and the right
rises with p: one root, in closed form on either branch (free: F = 0, the proxy relaxes onto
the device; in contact: linear). The device is rendered F(p) >= 0: the proxy never pulls, and
the force is continuous in x.

Defaults (``Coupling()``): k = ``stiffness_ratio`` / c_static = 5 times the tissue's static
stiffness under the tip (the step reply's ``static_compliance``), so that the settled rendered
stiffness 1 / (c_static + 1 / k) is 5/6 of the tissue's own; B = k_series T with
k_series = 1 / (c + 1 / k) the stiffness the device feels within a tick, so that the damper
dissipates at least what sampling a spring of that stiffness at the period T generates (k T / 2,
Colgate and Schenkel 1997), twice over. A softer coupling than the tissue's one-step stiffness
also filters what a position-driven tip would feel of the tissue's inertia: a press at speed v
from rest meets a force of at most about k v T in its first tick, where a rigid tip (the
coupling's k infinite) takes the whole one-step impulse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

__all__ = ["Contact", "Coupling", "Proxy", "balance", "couple"]


class Contact(NamedTuple):
    """A server step's contact under the tip, as the haptic loop renders it.

    Attributes:
        free: z, the tissue's displacement under the tip at the step's end without the contact
            (along +axis; scene units).
        compliance: c, the one-step compliance under the tip (displacement per unit force);
            NaN or not > 0: nothing to press (the tip was outside the domain).
        static_compliance: the static compliance under the tip (NaN: unknown, from a server
            that does not send it; the default coupling then scales to ``compliance``).
        k: the step it comes from (the session's step count after it).
    """

    free: float
    compliance: float
    static_compliance: float = math.nan
    k: int = 0

    @staticmethod
    def ahead(next_free: float, compliance: float, static: float, k: int) -> Contact:
        """From a ``lookahead`` step's reading: the next step's free displacement."""
        if not (math.isfinite(compliance) and compliance > 0.0 and math.isfinite(next_free)):
            return Contact(0.0, math.nan, math.nan, k)
        return Contact(next_free, compliance, static, k)

    @property
    def touchable(self) -> bool:
        return math.isfinite(self.compliance) and self.compliance > 0.0

    def force(self, depth: float) -> float:
        """F(depth) = max(0, (z + depth) / c): this step's force on a tip held at ``depth``."""
        if not self.touchable:
            return 0.0
        return max(0.0, (self.free + depth) / self.compliance)


class Proxy(NamedTuple):
    """The coupling's state after a tick: the proxy's and the device's depths, the force."""

    depth: float = 0.0
    device: float = 0.0
    force: float = 0.0


@dataclass(frozen=True)
class Coupling:
    """A virtual coupling (module docstring).

    Attributes:
        stiffness: k (force per length, scene units); None: ``stiffness_ratio`` / c.
        damping: B (force per velocity); None: k_series T (module docstring).
        stiffness_ratio: k c when ``stiffness`` is None.
    """

    stiffness: float | None = None
    damping: float | None = None
    stiffness_ratio: float = 5.0

    def __post_init__(self) -> None:
        for name, least in (("stiffness", 0.0), ("damping", -1.0)):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > least and value >= 0):
                bound = "> 0" if name == "stiffness" else ">= 0"
                raise ValueError(f"a coupling's {name} must be a finite number {bound}: {value!r}")
        if not (math.isfinite(self.stiffness_ratio) and self.stiffness_ratio > 0.0):
            raise ValueError(f"stiffness_ratio must be > 0, got {self.stiffness_ratio!r}")

    def gains(self, contact: Contact, period: float) -> tuple[float, float]:
        """(k, B) for ``contact`` at the loop's ``period`` (s)."""
        c = contact.compliance if contact.touchable else math.inf
        static = contact.static_compliance
        scale = static if math.isfinite(static) and static > 0.0 else c
        k = self.stiffness if self.stiffness is not None else self.stiffness_ratio / scale
        if self.damping is not None:
            return k, self.damping
        series = 0.0 if k == 0.0 else 1.0 / (c + 1.0 / k)
        return k, series * period

    def render(self, device: float, previous: Proxy, contact: Contact, period: float) -> Proxy:
        """The proxy and the force after a tick that moved the device to depth ``device``."""
        if not contact.touchable:  # nothing to press: the proxy is the device
            return Proxy(device, device, 0.0)
        k, b = self.gains(contact, period)
        return couple(device, previous, contact, k, b / period)


def couple(device: float, previous: Proxy, contact: Contact, k: float, damper: float) -> Proxy:
    """``Coupling.render`` with its gains given (k, and B / T as ``damper``) on a touchable
    contact."""
    depth, force = balance(
        device, previous.device, previous.depth, contact.free, contact.compliance, k, damper
    )
    return Proxy(depth, device, force)


def balance(
    device: float,
    device_before: float,
    proxy_before: float,
    free: float,
    compliance: float,
    k: float,
    damper: float,
) -> tuple[float, float]:
    """``couple`` on plain numbers: the proxy's depth and the force, from the device's depth
    now and the device's and proxy's depths a tick before. What the servo thread calls each
    tick (no objects built: a few microseconds matter there)."""
    # the proxy's balance without the tissue's force: k (x - p) + damper (x - x0 + p0 - p) = 0
    pulled = k * device + damper * (device - device_before + proxy_before)
    stiff = k + damper
    if free + pulled / stiff <= 0.0:
        return pulled / stiff, 0.0
    depth = (pulled - free / compliance) / (stiff + 1.0 / compliance)
    return depth, max(0.0, (free + depth) / compliance)
