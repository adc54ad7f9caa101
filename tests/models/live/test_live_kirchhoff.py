"""The nonlinear string live (live.kirchhoff) against the Galerkin reference and itself: its
energy, its order in dt, its linear limit, and contact under the step's tension."""

from __future__ import annotations

import numpy as np
import pytest

from membrane_models.exact.kirchhoff_carrier import KirchhoffString, solve_kirchhoff
from membrane_models.live import ModalEngine
from membrane_models.live.errors import InvalidEngineSettings
from membrane_models.live.interface import Grasp, Load, Probe, Tool
from membrane_models.live.kirchhoff import KirchhoffEngine, build_kirchhoff_engine
from membrane_models.problems import StringKirchhoff, make_problem

X = np.linspace(0.0, 1.0, 130)
MODES = np.zeros(128)
MODES[[0, 2, 4]] = 0.03, 0.01, 0.004  # nonlinearity k S* / c^2 = 1.09: the strong band


def _shape() -> np.ndarray:
    return np.sin(np.outer(X, np.pi * np.arange(1, 129))) @ MODES


def _run(dt: float, seconds: float = 1.0, stretch: float = 100.0) -> np.ndarray:
    engine = KirchhoffEngine(StringKirchhoff(stretch=stretch), 130, dt)
    state = engine.start(_shape()).state
    for _ in range(round(seconds / dt)):
        state = engine.step(state, frame=False).state
    return np.asarray(state.q)


def test_it_follows_the_galerkin_reference_at_second_order() -> None:
    reference = solve_kirchhoff(KirchhoffString(1.0, 100.0), MODES, np.zeros(128), [0.0, 1.0])
    expected = reference.q[-1]
    errors = [np.linalg.norm(_run(dt) - expected) / np.linalg.norm(expected) for dt in
              (2e-3, 1e-3)]  # fmt: skip
    assert errors[1] < 2e-4  # measured 1.50e-4 at the scene's dt, over 1 s
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=0.05)  # second order


def test_without_damping_or_input_it_keeps_its_energy() -> None:
    engine = KirchhoffEngine(StringKirchhoff(), 130, 1e-3)
    state = engine.start(_shape()).state
    start = engine.energy(state)
    energies = []
    for _ in range(1000):
        state = engine.step(state, frame=False).state
        energies.append(engine.energy(state))
    assert (max(energies) - min(energies)) / start < 1e-10  # measured 4.8e-13
    assert engine.tension(state) > 1.3  # the stretch is real: 30 % and more above c^2 = 1


def test_without_stretch_it_is_the_linear_string_to_the_trapezoids_error() -> None:
    linear = ModalEngine(StringKirchhoff(stretch=0.0), 130, 1e-3)
    state = linear.start(_shape()).state
    for _ in range(1000):
        state = linear.step(state, frame=False).state
    ours = _run(1e-3, stretch=0.0)
    difference = np.linalg.norm(ours - state.q) / np.linalg.norm(state.q)
    assert difference < 1e-3  # the trapezoid's phase error (w dt)^2 / 12 per step; measured
    assert difference > 0.0


def test_probes_tools_and_grasps_hold_under_the_steps_tension() -> None:
    engine = KirchhoffEngine(StringKirchhoff(), 130, 1e-3)
    state = engine.start(_shape()).state
    for _ in range(50):
        state = engine.step(state, grasps=[Grasp((0.3,), 0.02, 0.02)]).state
    held = engine.step(state, grasps=[Grasp((0.3,), 0.02, 0.02)])
    assert held.grasps[0].displacement == pytest.approx(0.02, abs=1e-12)
    pressed = engine.step(state, tools=[Tool("sphere", (0.5,), 0.0, 0.05)])
    assert pressed.tools[0].force > 0.0
    assert pressed.tools[0].penetration < 1e-12
    probed = engine.step(state, probes=[Probe((0.5,), 0.0, 0.02)])
    assert probed.probes[0].force > 0.0
    assert probed.probes[0].gap == 0.0


@pytest.mark.slow
def test_a_slow_press_feels_the_tension_its_stretch_adds() -> None:
    # a point probe held 0.05 below the middle until the string settles (damping 0.3): the
    # static string is the triangle of stretch S = 4 d^2, tension c^2 + k S = 2 and force
    # 4 d T = 0.4, twice the slack string's 0.2 (the 128 modes' point compliance: within 1 %)
    depth = 0.05
    engine = KirchhoffEngine(StringKirchhoff(), 130, 1e-3, damping=0.3)
    state = engine.start().state
    for _ in range(6000):
        result = engine.step(state, probes=[Probe((0.5,), depth, 0.0)], frame=False)
        state = result.state
    assert engine.tension(state) == pytest.approx(2.0, rel=0.01)
    assert result.probes[0].force == pytest.approx(4 * depth * 2.0, rel=0.01)


def test_it_is_built_for_its_problem_only() -> None:
    with pytest.raises(InvalidEngineSettings, match="string-kirchhoff"):
        build_kirchhoff_engine(make_problem("string-plucked"), (130,), 1e-3, {})
    with pytest.raises(InvalidEngineSettings, match="unknown"):
        build_kirchhoff_engine(StringKirchhoff(), (130,), 1e-3, {"hold": "foh"})
    engine = build_kirchhoff_engine(StringKirchhoff(), (130,), 1e-3, {"damping": 0.01})
    assert engine.describe()["engine"] == "kirchhoff"
    assert engine.describe()["stretch"] == 100.0


class _Counted(KirchhoffEngine):
    """The engine with its solves and whole steps counted (each ``advance`` its
    ``_solve_step`` takes; a compiled step under loads alone takes neither)."""

    solves = 0
    whole_steps = 0

    def _solve_step(self, state, advance, constrained, rows=None):  # type: ignore[no-untyped-def]
        def counted(tr):  # type: ignore[no-untyped-def]
            self.whole_steps += 1
            return advance(tr)

        self.solves += 1
        return super()._solve_step(state, counted, constrained, rows)


def _inputs(i: int) -> dict[str, list[object]]:
    """A haptic loop's inputs, changing every step: free, a load, a probe, grasps and a probe."""
    steps: list[dict[str, list[object]]] = [
        {},
        {"loads": [Load((0.3,), 2.0 * np.sin(i / 20), 0.02)]},
        {"probes": [Probe((0.3 + 0.2 * np.sin(i / 50),), 0.03 * np.sin(i / 30), 0.02)]},
        {"grasps": [Grasp((0.3,), 0.02, 0.02)]},
        {"grasps": [Grasp((0.3,), 0.02, 0.02), Grasp((0.7,), -0.01 * np.cos(i / 40), 0.0)],
         "probes": [Probe((0.5,), 0.005, 0.0)], "loads": [Load((0.2,), 0.3, 0.02)]},
    ]  # fmt: skip
    return steps[(i // 40) % 5]


@pytest.mark.parametrize("compiled", [True, False])
def test_the_tension_is_solved_with_the_contact_before_the_whole_step(compiled: bool) -> None:
    # loads, probes and grasps enter the tension's Newton (their rows), so each step takes
    # one whole step: the secant on whole steps is left to tools
    if compiled:
        pytest.importorskip("numba")
    engine = _Counted(StringKirchhoff(), 130, 1e-3, damping=0.01, compiled=compiled)
    state = engine.start(_shape()).state
    for i in range(400):
        state = engine.step(state, frame=False, **_inputs(i)).state  # type: ignore[arg-type]
    assert engine.solves >= 240  # the steps with probes or grasps at least
    assert engine.whole_steps == engine.solves


def test_the_compiled_kernel_steps_as_numpy_does_to_rounding() -> None:
    pytest.importorskip("numba")
    for damping in (0.0, 0.02):
        compiled = KirchhoffEngine(StringKirchhoff(), 130, 1e-3, damping=damping, compiled=True)
        reference = KirchhoffEngine(StringKirchhoff(), 130, 1e-3, damping=damping,
                                    compiled=False)  # fmt: skip
        state = compiled.start(_shape()).state
        worst = 0.0
        for i in range(400):
            inputs = _inputs(i)
            ours = compiled.step(state, frame=False, **inputs).state  # type: ignore[arg-type]
            same = reference.start(_shape()).state.__class__(
                state.step, state.time, state.q, state.v, state.load_force, state.applied,
                reference._owner,  # the same start for the numpy path's step
            )  # fmt: skip
            theirs = reference.step(same, frame=False, **inputs).state  # type: ignore[arg-type]
            scale = float(np.abs(ours.q).max())
            worst = max(worst, float(np.abs(ours.q - theirs.q).max()) / scale)
            state = ours
        assert worst < 1e-14  # measured 3e-16: the same expressions, sums in another order


def test_a_step_under_loads_alone_is_the_general_paths_bit_for_bit() -> None:
    # the compiled kernel's whole step under loads (its tension and free step in one call)
    # against the stepping core's general path from the same states
    pytest.importorskip("numba")
    engine = KirchhoffEngine(StringKirchhoff(), 130, 1e-3, damping=0.02)
    assert engine.compiled
    state = engine.start(_shape()).state
    for i in range(300):
        loads = [] if (i // 50) % 2 == 0 else [Load((0.3,), 2.0 * np.sin(i / 20), 0.02)]
        ours = engine.step(state, loads)
        general = ModalEngine.step(engine, state, loads)
        assert np.array_equal(ours.state.q, general.state.q)
        assert np.array_equal(ours.state.v, general.state.v)
        assert np.array_equal(ours.state.load_force, general.state.load_force)
        assert ours.state.applied == general.state.applied
        assert ours.frame is not None and general.frame is not None
        assert np.array_equal(ours.frame, general.frame)
        state = ours.state
