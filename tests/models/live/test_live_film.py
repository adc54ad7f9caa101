"""A film is a live engine driven by the scene's own forcing: the two must agree.

The engine steps the `membrane` and `rope` scenes' forcing as one Gaussian load (first-order
hold) and is compared with the exact film on the scene's lattice, relative L2 over the lattice
and the frames t = dt .. 1. Truncation-free stepping (every mode the force excites) leaves only
the hold's error, second order in dt; the modes the lattice and step keep, with the static
correction, stay within 1.2x of it (the issue's figures).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from numpy.typing import NDArray

from membrane_models.exact.forced import forced_modal_solution
from membrane_models.live import ModalEngine, film_frames, film_load
from membrane_models.problems import MembraneForced, StringForced, make_problem

FloatArray = NDArray[np.float64]
EXPECTED_MEMBRANE = {0.01: 7.5e-4, 0.005: 1.9e-4, 0.0025: 4.7e-5}  # the issue's figures


def _lattice(shape: tuple[int, ...]) -> FloatArray:
    axes = [np.linspace(0.0, 1.0, n) for n in shape]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(shape))


def _exact_frames(
    problem: StringForced | MembraneForced, shape: tuple[int, ...], dt: float
) -> FloatArray:
    frames = forced_modal_solution(problem).on_points(_lattice(shape))
    return np.array([frames(k * dt) for k in range(1, round(1.0 / dt) + 1)])


def _error(engine: ModalEngine, problem: StringForced | MembraneForced, exact: FloatArray) -> float:
    frames = np.array(list(film_frames(engine, problem, len(exact))))
    return float(np.linalg.norm(frames - exact) / np.linalg.norm(exact))


@pytest.fixture(scope="module")
def membrane_errors() -> dict[float, tuple[float, float, float]]:
    """(truncation-free, kept + correction, kept without) per dt, for the membrane scene."""
    problem = make_problem("membrane-forced")
    assert isinstance(problem, MembraneForced)
    out = {}
    for dt in EXPECTED_MEMBRANE:
        exact = _exact_frames(problem, (20, 20), dt)
        free = ModalEngine(problem, 20, dt, hold="foh", modes=80, step_limit=None)
        kept = ModalEngine(problem, 20, dt, hold="foh")
        bare = ModalEngine(problem, 20, dt, hold="foh", static_correction=False)
        out[dt] = (_error(free, problem, exact), _error(kept, problem, exact),
                   _error(bare, problem, exact))  # fmt: skip
    return out


@pytest.mark.slow
def test_truncation_free_stepping_has_the_holds_second_order_error(
    membrane_errors: dict[float, tuple[float, float, float]],
) -> None:
    for dt, expected in EXPECTED_MEMBRANE.items():
        assert membrane_errors[dt][0] == pytest.approx(expected, rel=0.03)
    errors = [membrane_errors[dt][0] for dt in EXPECTED_MEMBRANE]
    for coarse, fine in itertools.pairwise(errors):
        assert 3.9 < coarse / fine < 4.1  # second order as dt halves


def test_kept_modes_with_the_correction_stay_within_the_issues_bound(
    membrane_errors: dict[float, tuple[float, float, float]],
) -> None:
    for free, kept, _bare in membrane_errors.values():
        assert kept <= 1.2 * free
        assert kept <= 1.001 * free  # measured: the correction leaves nothing visible
    # without the correction the dropped modes' static share is missing: a floor near 1e-3
    assert membrane_errors[0.0025][2] > 10.0 * membrane_errors[0.0025][1]


def test_rope_film_agrees_at_second_order() -> None:
    problem = make_problem("string-forced")
    assert isinstance(problem, StringForced)
    errors = []
    for dt in (0.01, 0.005):
        exact = _exact_frames(problem, (100,), dt)
        free = _error(ModalEngine(problem, 100, dt, hold="foh", modes=200, step_limit=None),
                      problem, exact)  # fmt: skip
        kept = _error(ModalEngine(problem, 100, dt, hold="foh"), problem, exact)
        assert kept <= 1.2 * free
        errors.append(kept)
    assert 3.8 < errors[0] / errors[1] < 4.2


def test_zero_order_hold_film_is_first_order() -> None:
    problem = make_problem("membrane-forced")
    assert isinstance(problem, MembraneForced)
    errors = []
    for dt in (0.01, 0.005):
        exact = _exact_frames(problem, (20, 20), dt)
        errors.append(_error(ModalEngine(problem, 20, dt), problem, exact))
    assert 1.8 < errors[0] / errors[1] < 2.2


def test_film_load_is_the_problems_forcing() -> None:
    """The load's pressure F / (pi r^2) exp(-rho^2 / r^2) is the study's -h g(t) exp(-k rho^2)."""
    problem = make_problem("membrane-forced")
    assert isinstance(problem, MembraneForced)
    load = film_load(problem, 0.37)
    assert load.at == (problem.x0, problem.y0)
    assert load.radius == pytest.approx(0.05)
    x, y = 0.83, 0.46
    rho2 = (x - problem.x0) ** 2 + (y - problem.y0) ** 2
    pressure = load.force / (math.pi * load.radius**2) * math.exp(-rho2 / load.radius**2)
    assert pressure == pytest.approx(float(problem.forcing(x, y, 0.37)), rel=1e-12)
    assert load.force < 0.0  # the study's force pushes along -axis, like a probe
    string = make_problem("string-forced")
    assert isinstance(string, StringForced)
    line = film_load(string, 0.5)
    density = line.force / (math.sqrt(math.pi) * line.radius) * math.exp(-(0.01**2) / 0.05**2)
    assert density == pytest.approx(float(string.forcing(string.x0 + 0.01, 0.5)), rel=1e-12)
