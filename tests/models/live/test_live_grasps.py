"""Grasps: a point held exactly at a commanded height, alone and beside probes, against the
settled string's closed forms (problem units: T = c^2 = 100 on string-forced)."""

from __future__ import annotations

import numpy as np
import pytest

from membrane_models.live import ModalEngine, ModalState, Probe
from membrane_models.live.errors import InvalidGrasp
from membrane_models.live.interface import Grasp, StepResult
from membrane_models.problems import make_problem

STRING = make_problem("string-forced")
TENSION = 100.0  # c^2 with c = 10
SETTLED_STEPS = 600  # damping 0.5: the fundamental decays by e in 1 / (0.5 * 10 pi) = 64 ms


def _settled(
    engine: ModalEngine, probes: list[Probe], grasps: list[Grasp]
) -> StepResult[ModalState]:
    state = engine.start().state
    for _ in range(SETTLED_STEPS):
        result = engine.step(state, [], probes, frame=False, grasps=grasps)
        state = result.state
    return result


@pytest.mark.parametrize("x0", [0.3, 0.5, 0.85])
def test_a_grasp_pulling_a_point_needs_the_strings_static_force(x0: float) -> None:
    """F = T d / (x0 (1 - x0)), the point force that holds x0 at d."""
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    d = 1e-3
    result = _settled(engine, [], [Grasp((x0,), d, 0.0)])
    reading = result.grasps[0]
    assert reading.displacement == pytest.approx(d, rel=1e-10)
    assert reading.force == pytest.approx(TENSION * d / (x0 * (1 - x0)), rel=1e-4)
    assert result.probes == ()


def test_a_grasp_pushing_down_needs_a_force_of_the_other_sign() -> None:
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    reading = _settled(engine, [], [Grasp((0.4,), -2e-3, 0.0)]).grasps[0]
    assert reading.force == pytest.approx(-TENSION * 2e-3 / (0.4 * 0.6), rel=1e-4)


def test_a_grasp_and_a_probe_solve_together_as_the_piecewise_linear_string() -> None:
    """A grasp at a lifts to d1, a probe at b holds -d2: the string is straight between them,
    and each force is T times its kink, P = T (u'(x-) - u'(x+))."""
    a, b, d1, d2 = 0.3, 0.7, 1e-3, 5e-4
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    result = _settled(engine, [Probe((b,), d2, 0.0)], [Grasp((a,), d1, 0.0)])
    grasp, probe = result.grasps[0], result.probes[0]
    assert probe.in_contact and probe.displacement == pytest.approx(-d2, rel=1e-9)
    assert grasp.force == pytest.approx(TENSION * (d1 / a + (d1 + d2) / (b - a)), rel=1e-4)
    pushed = -TENSION * ((-(d1 + d2)) / (b - a) - d2 / (1 - b))
    assert probe.force == pytest.approx(pushed, rel=1e-4)


def test_a_probe_above_what_a_grasp_lifts_touches_nothing() -> None:
    """The probe's face 2e-3 above the rest surface, the grasp lifting x = 0.5 to 1e-3: at
    x = 0.55 the string reaches 0.9e-3, so the probe's force is 0 and its gap 1.1e-3."""
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    result = _settled(engine, [Probe((0.55,), -2e-3, 0.0)], [Grasp((0.5,), 1e-3, 0.0)])
    probe = result.probes[0]
    assert probe.force == 0.0 and not probe.in_contact
    assert probe.gap == pytest.approx(2e-3 - 0.9e-3, rel=1e-4)
    assert result.grasps[0].force == pytest.approx(TENSION * 1e-3 / 0.25, rel=1e-4)


def test_grasps_that_cannot_hold_are_refused_and_bad_values_named() -> None:
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    state = engine.start().state
    with pytest.raises(InvalidGrasp, match="clamped point"):
        engine.step(state, grasps=[Grasp((0.0,), 1e-3, 0.0)])
    with pytest.raises(InvalidGrasp, match="two hold one point"):
        engine.step(state, grasps=[Grasp((0.5,), 1e-3, 0.0), Grasp((0.5,), 2e-3, 0.0)])
    with pytest.raises(InvalidGrasp, match=r"grasp 0: height must be in \[-1000, 1000\]"):
        engine.step(state, grasps=[Grasp((0.5,), 2e3, 0.0)])
    with pytest.raises(InvalidGrasp, match="at most 8 grasps"):
        engine.step(state, grasps=[Grasp((0.1 * i,), 0.0, 0.0) for i in range(9)])
    with pytest.raises(InvalidGrasp, match="must be a Grasp"):
        engine.step(state, grasps=[Probe((0.5,), 0.0, 0.0)])  # type: ignore[list-item]


def test_a_grasp_keeps_the_state_immutable_and_frames_show_the_hold() -> None:
    engine = ModalEngine(STRING, 101, 0.001, damping=0.5)
    start = engine.start().state
    result = engine.step(start, grasps=[Grasp((0.5,), 1e-3, 0.0)])
    assert start.step == 0 and result.state.step == 1
    assert result.frame is not None
    x = np.linspace(0.0, 1.0, 101)
    assert result.frame[np.argmin(abs(x - 0.5))] == pytest.approx(1e-3, rel=1e-6)
