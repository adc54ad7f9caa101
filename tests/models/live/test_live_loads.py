"""Loads (at, force, radius): static limits against closed forms, linearity, and bad values.

The engine takes its own ``Load``; the form of a load's wire map is the client's live schema's
to check (tests/client/test_live_schema.py)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.integrate import quad

from membrane_models.exact.spectrum import gaussian_sine_integrals
from membrane_models.live import InvalidLoad, Load, ModalEngine, ModalState
from membrane_models.live.cost import StepTooCostly
from membrane_models.live.inputs import MAX_LOADS
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]
STRING = make_problem("string-forced")  # c = 10
MEMBRANE = make_problem("membrane-forced")  # c = 5


def _string_green(x: FloatArray, a: float, c: float) -> FloatArray:
    return np.where(x <= a, x * (1.0 - a), a * (1.0 - x)) / c**2


def _poisson_sum(at: tuple[float, float], radius: float, n: int, modes: int = 240) -> FloatArray:
    """The membrane's static deflection per unit force on an n x n lattice, as a mode sum."""
    m = np.arange(1, modes + 1)
    scale = 2.0 / (math.sqrt(math.pi) * radius)
    sx = scale * gaussian_sine_integrals(m, at[0], 1.0 / radius**2)
    sy = scale * gaussian_sine_integrals(m, at[1], 1.0 / radius**2)
    weights = 1.0 / ((MEMBRANE.c * math.pi) ** 2 * (m[:, None] ** 2 + m[None, :] ** 2))
    table = np.sin(np.pi * np.outer(np.linspace(0.0, 1.0, n), m))
    return np.asarray((table @ (np.outer(sx, sy) * weights) @ table.T).reshape(-1))


def _held(engine: ModalEngine, loads: list[Any], steps: int = 300) -> FloatArray:
    state = engine.start().state
    for _ in range(steps):
        state = engine.step(state, loads, frame=False).state
    return engine.frame(state)


def _relative(a: FloatArray, b: FloatArray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_string_point_load_held_gives_the_closed_form_static_deflection() -> None:
    truth = 0.3 * _string_green(np.linspace(0.0, 1.0, 100), 0.37, STRING.c)
    # dt = 0.05 keeps 2 modes (w dt <= pi): the correction carries the rest
    corrected = ModalEngine(STRING, 100, 0.05, damping=0.7)
    assert corrected.modes.count == 2
    assert _relative(_held(corrected, [Load((0.37,), 0.3, 0.0)]), truth) < 1e-9
    bare = ModalEngine(STRING, 100, 0.05, damping=0.7, static_correction=False)
    assert _relative(_held(bare, [Load((0.37,), 0.3, 0.0)]), truth) > 0.05


def test_string_gaussian_load_is_normalised_to_its_total_force() -> None:
    """Static deflection = int G(x, s) F g(s) ds over the domain, g normalised over the line."""
    x0, radius, force = 0.9, 0.08, 0.4  # near an edge: part of the Gaussian is on the support
    x = np.linspace(0.0, 1.0, 100)

    def deflection(point: float) -> float:
        def integrand(s: float) -> float:
            g = math.exp(-((s - x0) ** 2) / radius**2) / (math.sqrt(math.pi) * radius)
            return float(_string_green(np.array(point), s, STRING.c)) * g

        return force * quad(integrand, 0.0, 1.0, points=[point, x0], epsabs=1e-15)[0]

    truth = np.array([deflection(p) for p in x])
    engine = ModalEngine(STRING, 100, 0.05, damping=0.7)
    assert _relative(_held(engine, [Load((x0,), force, radius)]), truth) < 1e-8


@pytest.mark.parametrize(
    ("at", "bound"),
    [((0.3, 0.6), 1e-9), ((0.5, 0.5), 1e-9), ((0.97, 0.04), 1e-4)],  # a corner: edges cut it
)
def test_membrane_load_held_gives_its_poisson_sum(at: tuple[float, float], bound: float) -> None:
    truth = 0.2 * _poisson_sum(at, 0.05, 20, modes=1024)
    corrected = ModalEngine(MEMBRANE, 20, 0.05, damping=0.7)  # 8 modes stepped
    assert _relative(_held(corrected, [Load(at, 0.2, 0.05)]), truth) < bound
    bare = ModalEngine(MEMBRANE, 20, 0.05, damping=0.7, static_correction=False)
    assert _relative(_held(bare, [Load(at, 0.2, 0.05)]), truth) > 0.1


@pytest.mark.slow
def test_time_averaged_undamped_response_is_the_static_one() -> None:
    truth = _string_green(np.linspace(0.0, 1.0, 100), 0.61, STRING.c)
    engine = ModalEngine(STRING, 100, 0.0123)
    state = engine.start().state
    total = np.zeros(100)
    steps = 20000
    for _ in range(steps):
        state = engine.step(state, [Load((0.61,), 1.0, 0.0)], frame=False).state
        total += engine.frame(state)
    assert _relative(total / steps, truth) < 1e-3


def test_larger_than_the_domain_load_presses_mostly_on_the_support() -> None:
    radius = 5.0
    truth = 0.5 * _poisson_sum((0.5, 0.5), radius, 20, modes=1024)
    engine = ModalEngine(MEMBRANE, 20, 0.05, damping=0.7)
    assert _relative(_held(engine, [Load((0.5, 0.5), 0.5, radius)]), truth) < 1e-5


def test_loads_superpose() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.004)
    first = [Load((0.2, 0.7), 0.3, 0.05)]
    second = [Load((0.6, 0.45), -0.2, 0.1)]
    both = _held(engine, [*first, *second], 50)
    apart = _held(engine, first, 50) + _held(engine, second, 50)
    np.testing.assert_allclose(both, apart, rtol=0, atol=1e-12 * np.abs(both).max())


def test_first_order_hold_ramps_from_the_last_steps_loads() -> None:
    """Under FOH a load held from step 1 ramps up over the first step only: from then on the
    two holds differ by the response to that first ramp (a free vibration), not drifting."""
    load = [Load((0.4, 0.4), 0.1, 0.05)]
    zoh, foh = ModalEngine(MEMBRANE, 20, 0.01), ModalEngine(MEMBRANE, 20, 0.01, hold="foh")
    z, f = zoh.start().state, foh.start().state
    for _ in range(30):
        z, f = zoh.step(z, load).state, foh.step(f, load).state
    # the FOH start lags by half a step of force: the energy difference is small, not zero
    diff = zoh.energy(z) - foh.energy(f)
    assert diff != 0.0
    assert abs(diff) < 0.2 * zoh.energy(z)


def _load(at: Any, force: Any, radius: Any) -> Any:
    """A Load with fields of any type: what a caller may pass, whatever the annotations say."""
    return Load(at, force, radius)


BAD_LOADS: list[tuple[Any, str]] = [
    (Load((0.5, 0.5), math.nan, 0.05), "finite"),
    (Load((0.5, 0.5), math.inf, 0.05), "finite"),
    (Load((0.5, 0.5), -math.inf, 0.05), "finite"),
    (Load((0.5, math.nan), 1.0, 0.05), "finite"),
    (Load((0.5, 0.5), 1.0, 0.0), "logarithmically singular"),
    (Load((0.5, 0.5), 1.0, 1e-3), "smallest"),
    (Load((0.5, 0.5), 1.0, -0.1), ">= 0"),
    (Load((1.2, 0.5), 1.0, 0.05), "outside"),
    (Load((0.5,), 1.0, 0.05), "2 coordinates"),
    (_load((0.5, 0.5), "1", 0.05), "number"),
    (_load((0.5, 0.5), True, 0.05), "number"),
    ([0.5, 0.5, 1.0], "must be a Load, got list"),
    ({"at": [0.5, 0.5], "force": 1.0, "radius": 0.05}, "must be a Load, got dict"),  # a wire map
    (Load((0.5, 0.5), 1e308, 0.05), "at most 1e"),
    (_load((0.5, 0.5), 2**63, 0.05), "at most 1e"),
    (_load((0.5, 0.5), 10**400, 0.05), "finite"),
    (Load((0.5, 0.5), -1e7, 0.05), "at most 1e"),
    (Load((0.5, 0.5), 1.0, 1e-310), "smallest"),
    (Load((0.5, 0.5), 1.0, 5e-324), "smallest"),
    (Load((0.5, 0.5), 1.0, 1e9), "at most 10"),
]


@pytest.mark.parametrize(("load", "message"), BAD_LOADS)
def test_bad_loads_raise_and_leave_the_state_intact(load: Any, message: str) -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.01)
    state = engine.step(engine.start().state, [Load((0.3, 0.3), 0.1, 0.05)]).state
    before = (state.q.copy(), state.v.copy(), state.step)
    with pytest.raises(InvalidLoad, match=message):
        engine.step(state, [Load((0.6, 0.6), 0.1, 0.05), load])
    assert _unchanged(state, before)
    # the same state still steps, exactly as a fresh copy would
    again = engine.step(state, [Load((0.6, 0.6), 0.1, 0.05)])
    assert again.state.step == state.step + 1


def _unchanged(state: ModalState, before: tuple[FloatArray, FloatArray, int]) -> bool:
    q, v, step = before
    return bool(np.array_equal(state.q, q) and np.array_equal(state.v, v)) and state.step == step


def test_too_many_loads_and_a_string_radius_below_the_smallest() -> None:
    engine = ModalEngine(MEMBRANE, 20, 0.01)
    state = engine.start().state
    with pytest.raises(InvalidLoad, match=f"at most {MAX_LOADS}"):
        engine.step(state, [Load((0.5, 0.5), 0.0, 0.05)] * (MAX_LOADS + 1))
    with pytest.raises(InvalidLoad, match="list"):
        engine.step(state, {"at": [0.5, 0.5], "force": 1.0, "radius": 0.05})  # type: ignore[arg-type]
    string = ModalEngine(STRING, 100, 0.01)
    with pytest.raises(InvalidLoad, match="0 is a point force"):
        string.step(string.start().state, [Load((0.5,), 1.0, 1e-6)])
    assert string.min_radius == pytest.approx(4.0 / 2**18, rel=1e-6)


def test_loads_accept_scalar_at_on_the_string_and_numpy_numbers() -> None:
    engine = ModalEngine(STRING, 100, 0.01)
    state = engine.start().state
    a = engine.step(state, [_load(0.4, np.float64(0.2), 0)]).frame
    b = engine.step(state, [Load((0.4,), 0.2, 0.0)]).frame
    c = engine.step(state, [_load(np.array([0.4]), np.float32(0.2), np.int64(0))]).frame
    assert a is not None and b is not None and c is not None
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(c, b, rtol=1e-7, atol=0)  # float32(0.2) is not quite 0.2


def test_a_step_over_the_cost_budget_is_refused_with_its_figure() -> None:
    """64 loads at the smallest radius cost about 0.35 s of frame each time before the budget;
    now the step is priced first and refused, the state untouched, and a cheaper step passes."""
    engine = ModalEngine(MEMBRANE, 20, 0.001, damping=0.02)
    state = engine.start().state
    tiny = [Load((0.3 + 0.005 * i, 0.5), 1.0, engine.min_radius) for i in range(MAX_LOADS)]
    with pytest.raises(StepTooCostly, match=r"about [0-9.]+ ms of work, over the 5 ms"):
        engine.step(state, tiny)
    half = Load((0.5, 0.5), 1.0, 2 * engine.min_radius)
    assert engine.step(state, [half]).state.step == 1  # one at twice the radius is within it
    wide = [Load((0.3 + 0.005 * i, 0.5), 1.0, 0.05) for i in range(MAX_LOADS)]
    assert engine.step(state, wide).state.step == 1  # today's typical loads stay legal
    string = ModalEngine(STRING, 100, 0.001)
    held = [Load((0.2 + 0.01 * i,), 1.0, 4 * string.min_radius) for i in range(2)]
    with pytest.raises(StepTooCostly, match="bytes of spectra"):
        string.step(string.start().state, held)
