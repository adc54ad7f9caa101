"""The virtual coupling against its own equations: the proxy's balance, the settled stiffness,
the energy a sampled spring would make and the damper takes back, never a pull."""

from __future__ import annotations

import math

import numpy as np
import pytest

from membrane_client.haptics import Contact, Coupling, Proxy

PERIOD = 1e-3
# membrane-live's centre under a soft tip of radius 0.05: one-step and static compliances
ONE_STEP, STATIC = 3.1725e-05, 0.014772


def _press(coupling: Coupling, contact: Contact, depths: np.ndarray) -> np.ndarray:
    proxy, forces = Proxy(), []
    for x in depths:
        proxy = coupling.render(float(x), proxy, contact, PERIOD)
        forces.append(proxy.force)
    return np.array(forces)


def test_the_proxy_balances_the_coupling_against_the_tissue() -> None:
    contact = Contact(-2e-4, ONE_STEP, STATIC)
    coupling = Coupling()
    k, b = coupling.gains(contact, PERIOD)
    assert k == pytest.approx(5.0 / STATIC) and b == pytest.approx(PERIOD / (ONE_STEP + 1 / k))
    before = Proxy(3e-4, 3.5e-4, 0.0)
    after = coupling.render(5e-4, before, contact, PERIOD)
    spring = k * (5e-4 - after.depth)
    damper = b * ((5e-4 - 3.5e-4) - (after.depth - before.depth)) / PERIOD
    assert after.force > 0 and spring + damper == pytest.approx(after.force, rel=1e-12)
    assert after.force == pytest.approx((contact.free + after.depth) / ONE_STEP, rel=1e-12)


def test_the_settled_rendered_stiffness_is_five_sixths_of_the_tissues() -> None:
    settled = Contact(0.0, STATIC, STATIC)  # a tissue at rest: the step is its static response
    forces = _press(Coupling(), settled, np.full(50, 1e-3))
    assert forces[-1] == pytest.approx(1e-3 / STATIC * 5 / 6, rel=1e-9)


def test_the_force_never_pulls_and_is_continuous_in_the_device() -> None:
    contact = Contact(-1e-4, ONE_STEP, STATIC)
    depths = np.concatenate([np.linspace(0, 3e-4, 3000), np.linspace(3e-4, -1e-4, 4000)])
    forces = _press(Coupling(), contact, depths)
    assert forces.min() == 0.0 and forces.max() > 0.0
    k, b = Coupling().gains(contact, PERIOD)  # a tick's slope is at most the spring's and damper's
    assert np.abs(np.diff(forces)).max() <= (k + b / PERIOD) * np.abs(np.diff(depths)).max()
    clear = Contact(0.0, math.nan)  # outside the domain: nothing to press, the proxy is the device
    assert Coupling().render(1e-3, Proxy(), clear, PERIOD) == Proxy(1e-3, 1e-3, 0.0)


def test_over_closed_cycles_the_damper_takes_back_what_sampling_makes() -> None:
    """A spring sampled at T makes energy (-k dx^2 / 2 a tick, Colgate and Schenkel): without
    the damper the device gains it over closed cycles; with the default it does not."""
    contact = Contact(0.0, ONE_STEP, STATIC)
    t = np.arange(4000) * PERIOD
    depths = 5e-4 * (1 - np.cos(2 * math.pi * 7 * t)) / 2  # 28 presses at 7 Hz
    for coupling, sign in ((Coupling(), 1.0), (Coupling(damping=0.0), -1.0)):
        forces = _press(coupling, contact, depths)
        work = float(np.sum(forces[:-1] * np.diff(depths)))  # by the hand on the device
        assert sign * work > 0.0


def test_bad_couplings_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match="stiffness must be a finite number > 0"):
        Coupling(stiffness=0.0)
    with pytest.raises(ValueError, match="damping must be a finite number >= 0"):
        Coupling(damping=-1.0)
    with pytest.raises(ValueError, match="stiffness_ratio must be > 0"):
        Coupling(stiffness_ratio=math.nan)
