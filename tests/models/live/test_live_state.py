"""Initial shapes, immutable states, settings, and the interface other engines implement."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from membrane_models.exact.plucked import PluckedDAlembert
from membrane_models.live import (
    InvalidEngineSettings,
    InvalidShape,
    InvalidState,
    LiveEngine,
    ModalEngine,
    ModalState,
    Probe,
)
from membrane_models.problems import StringPlucked, make_problem

FloatArray = NDArray[np.float64]
MEMBRANE = make_problem("membrane-forced")
STRING = make_problem("string-forced")


def _grid(n: int) -> tuple[FloatArray, FloatArray]:
    x = np.linspace(0.0, 1.0, n)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    return xx, yy


def test_a_shape_the_modes_carry_projects_exactly() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    x, y = _grid(20)
    shape = 2e-4 * np.sin(np.pi * x) * np.sin(2 * np.pi * y) - 1e-4 * np.sin(
        5 * np.pi * x
    ) * np.sin(3 * np.pi * y)
    start = engine.start(displacement=shape, velocity=shape.reshape(-1))
    assert start.displacement_residual < 1e-13 and start.velocity_residual < 1e-13
    assert start.state.q[0, 1] == pytest.approx(2e-4, rel=1e-12)
    assert start.state.q[4, 2] == pytest.approx(-1e-4, rel=1e-12)
    np.testing.assert_allclose(engine.frame(start.state), shape.reshape(-1), atol=1e-18)


def test_a_shape_the_modes_cannot_carry_shows_its_residual() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    x, _ = _grid(20)
    lifted = engine.start(displacement=np.full((20, 20), 1e-4))  # nonzero on clamped edges
    # the interior modes carry every interior value: what is left is the 76 edge points of 400
    assert lifted.displacement_residual == pytest.approx(math.sqrt(76 / 400), rel=1e-12)
    coarse = ModalEngine(MEMBRANE, 20, 0.01)  # drops the corner modes (w dt > pi)
    fine_detail = np.sin(17 * np.pi * x) * np.sin(17 * np.pi * x.T)
    assert coarse.start(displacement=fine_detail).displacement_residual == pytest.approx(1.0)
    assert engine.start(displacement=fine_detail).displacement_residual < 1e-12


@pytest.mark.parametrize("bad", ["nan", "inf", "size", "text"])
def test_bad_initial_shapes_raise(bad: str) -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    shape: object = np.zeros((20, 20))
    if bad == "nan":
        shape[3, 4] = math.nan  # type: ignore[index]
    elif bad == "inf":
        shape[0, 0] = math.inf  # type: ignore[index]
    elif bad == "size":
        shape = np.zeros(399)
    else:
        shape = "flat"
    with pytest.raises(InvalidShape):
        engine.start(displacement=shape)  # type: ignore[arg-type]
    with pytest.raises(InvalidShape):
        engine.start(velocity=shape)  # type: ignore[arg-type]


def test_a_plucked_rope_follows_dalemberts_solution() -> None:
    """A robot plucked the rope: start from the smoothed pluck on the lattice, step it."""
    problem = make_problem("string-plucked-smooth")
    assert isinstance(problem, StringPlucked)
    exact = PluckedDAlembert(problem)
    x = np.linspace(0.0, 1.0, 100)
    engine = ModalEngine(problem, 100, 0.01)
    start = engine.start(displacement=exact.at_points(x[:, None], [0.0])[:, 0])
    assert start.displacement_residual < 1e-6
    state = start.state
    worst = 0.0
    for k in range(1, 201):  # one period, 2 / c
        result = engine.step(state)
        state = result.state
        assert result.frame is not None
        truth = exact.at_points(x[:, None], [k * 0.01])[:, 0]
        worst = max(worst, float(np.abs(result.frame - truth).max()))
    assert worst < 1e-6 * problem.height


def test_states_are_values_a_retried_step_gives_the_same_answer() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.001)
    state = engine.start().state
    probe = [Probe((0.4, 0.5), 1e-5, 0.05)]
    first = engine.step(state, [], probe)
    again = engine.step(state, [], probe)
    assert first.probes == again.probes
    np.testing.assert_array_equal(first.state.q, again.state.q)
    assert state.step == 0 and not state.q.any()
    with pytest.raises(ValueError, match="read-only"):
        first.state.q[0, 0] = 1.0
    assert first.state.time == pytest.approx(0.001) and first.state.step == 1


def test_a_state_from_another_engine_is_refused() -> None:
    one, other = ModalEngine(MEMBRANE, 20, 0.001), ModalEngine(MEMBRANE, 20, 0.001)
    with pytest.raises(InvalidState):
        one.step(other.start().state)
    with pytest.raises(InvalidState):
        one.frame(other.start().state)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": math.nan}, "dt"),
        ({"damping": -0.1}, "damping"),
        ({"damping": math.inf}, "damping"),
        ({"hold": "linear"}, "hold"),
        ({"lattice": 2}, "lattice"),
        ({"lattice": (20, 20, 20)}, "lattice"),
        ({"modes": 0}, "modes"),
        ({"step_limit": -1.0}, "step_limit"),
        ({"modes": 2048}, "at most"),
    ],
)
def test_bad_settings_raise(settings: dict[str, object], message: str) -> None:
    options: dict[str, object] = {"lattice": 20, "dt": 0.01, **settings}
    lattice, dt = options.pop("lattice"), options.pop("dt")
    with pytest.raises(InvalidEngineSettings, match=message):
        ModalEngine(MEMBRANE, lattice, dt, **options)  # type: ignore[arg-type]


def test_the_mode_count_rule() -> None:
    # the lattice resolves n - 2 modes per axis; at display rate the step keeps w dt <= pi
    assert ModalEngine(MEMBRANE, 20, 0.001).modes.count == 18 * 18
    display = ModalEngine(MEMBRANE, 20, 0.01)
    m = np.arange(1, 19)
    expected = int((5.0 * math.pi * np.hypot(m[:, None], m[None, :]) * 0.01 <= math.pi).sum())
    assert display.modes.count == expected == 282
    wide = ModalEngine(MEMBRANE, 100, 0.01)  # a fine lattice at display rate: a small box
    assert wide.modes.box == (19, 19) and wide.modes.count < 400
    assert ModalEngine(STRING, (100,), 0.001).modes.count == 98
    assert ModalEngine(STRING, 100, 0.01, step_limit=None).modes.count == 98
    assert ModalEngine(MEMBRANE, (20, 12), 0.001).modes.box == (18, 10)


def test_the_interface_is_what_a_modal_engine_offers() -> None:
    engine: LiveEngine[ModalState] = ModalEngine(MEMBRANE, 20, 0.01)  # checked by mypy
    assert engine.spatial_dims == 2 and engine.lattice_shape == (20, 20) and engine.dt == 0.01
    result = engine.step(engine.start().state, [], [Probe((0.5, 0.5), 0.0, 0.1)])
    assert result.frame is not None and result.frame.shape == (400,)
    assert engine.frame(result.state).shape == (400,)
    described = ModalEngine(MEMBRANE, 20, 0.01).describe()
    assert described["modes_stepped"] == 282
    assert isinstance(described["memory_bytes"], int) and 0 < described["memory_bytes"] < 2**24
