"""Energy of the stepped modes: exact balance under zero-order hold, no drift, no growth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from membrane_models.live import Load, ModalEngine, ModalState, Probe
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]
MEMBRANE = make_problem("membrane-forced")
STRING = make_problem("string-forced")


def _shape(n: int) -> FloatArray:
    x = np.linspace(0.0, 1.0, n)
    return np.asarray(1e-4 * np.outer(np.sin(np.pi * x) ** 2 * x, np.sin(2.0 * np.pi * x)))


def test_change_of_energy_is_the_work_of_loads_and_probes() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    state = engine.start().state
    worst, contact_steps = 0.0, 0
    for k in range(600):
        load = Load((0.7, 0.4), 0.01 * math.sin(0.01 * k), 0.05)
        probe = Probe((0.35, 0.55), 1e-5 * (1.0 + math.sin(0.02 * k)), 0.05)
        before = engine.energy(state)
        result = engine.step(state, [load], [probe], frame=False, work=True)
        assert result.work is not None
        after = engine.energy(result.state)
        state = result.state
        contact_steps += result.probes[0].in_contact
        if after > 0.0:
            worst = max(worst, abs(after - before - result.work) / after)
    assert contact_steps > 100
    assert worst <= 1e-9  # measured: about 5e-16


def _free_run(engine: ModalEngine, state: ModalState, steps: int) -> ModalState:
    for _ in range(steps):
        state = engine.step(state, frame=False).state
    return state


def test_free_vibration_keeps_its_energy() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    state = engine.start(displacement=_shape(20)).state
    energy = engine.energy(state)
    assert energy > 0.0
    assert abs(engine.energy(_free_run(engine, state, 10**4)) / energy - 1.0) <= 1e-9


@pytest.mark.slow
def test_a_million_free_steps_keep_the_energy_to_1e_9() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    state = engine.start(displacement=_shape(20)).state
    energy = engine.energy(state)
    assert abs(engine.energy(_free_run(engine, state, 10**6)) / energy - 1.0) <= 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("zeta", [0.001, 0.3, 1.0, 3.0])
def test_damped_energy_never_grows_without_input(zeta: float) -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.002, damping=zeta)
    state = engine.start(displacement=_shape(20), velocity=_shape(20)).state
    energy = engine.energy(state)
    for _ in range(2000):
        state = engine.step(state, frame=False).state
        now = engine.energy(state)
        assert now <= energy
        energy = now
    assert energy < engine.energy(engine.start(displacement=_shape(20)).state)


def test_a_step_far_above_the_fastest_period_is_still_exact() -> None:
    """One step of 10.37 (about 600 periods of the fastest kept mode) equals 1000 steps of
    0.01037 under the same held load: both are exact, neither drifts."""
    coarse = ModalEngine(STRING, 100, 10.37, step_limit=None)
    fine = ModalEngine(STRING, 100, 0.01037, step_limit=None)
    assert coarse.modes.count == 98
    fastest = float(coarse.modes.omega.max())
    assert 500 * 2.0 * math.pi / fastest < 10.37
    load = [Load((0.31,), 0.7, 0.02)]
    one = coarse.step(coarse.start().state, load, frame=False).state
    many = fine.start().state
    for _ in range(1000):
        many = fine.step(many, load, frame=False).state
    scale = float(np.abs(many.q).max())
    assert float(np.abs(one.q - many.q).max()) <= 1e-9 * scale
    assert float(np.abs(one.v - many.v).max()) <= 1e-9 * float(np.abs(many.v).max())
    # and free vibration from a shape lands on cos(w t) exactly
    shape = np.sin(3.0 * np.pi * np.linspace(0.0, 1.0, 100))
    start = coarse.start(displacement=shape).state
    after = coarse.step(start, frame=False).state
    w = coarse.modes.omega[2]
    assert after.q[2] == pytest.approx(math.cos(w * 10.37), abs=1e-11)
