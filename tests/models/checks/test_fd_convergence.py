"""The finite-difference solver converges to the exact solutions at the expected order.

Leapfrog is second order in space and time, so with c dt / dx held fixed its error against the
exact solution should fall by 4x per halving of dx: this checks the exact solutions (an error
in them would stall the convergence) as much as the solver. The kinked triangle is the
exception: its initial kink limits any fixed-order scheme to first order in the L2 norm.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from membrane_models.checks.linear_fd import solve_fd
from membrane_models.exact import exact_solution
from membrane_models.problems import make_problem


def _errors(name: str, cells: list[int], n_times: int = 11) -> list[float]:
    """Relative L2 error of the FD solution over its space-time grid, per resolution."""
    problem = make_problem(name)
    exact = exact_solution(problem)
    t = np.linspace(0.0, problem.t_end, n_times)
    errors = []
    for n in cells:
        fd = solve_fd(problem, n, t)
        reference = exact.grid(*fd.axes, t)
        errors.append(float(np.linalg.norm(fd.u - reference) / np.linalg.norm(reference)))
    return errors


def _orders(errors: list[float]) -> list[float]:
    return [math.log2(a / b) for a, b in itertools.pairwise(errors)]


def test_forced_string_second_order() -> None:
    errors = _errors("string-forced", [50, 100, 200])
    orders = _orders(errors)
    assert all(1.9 < p < 2.1 for p in orders), orders
    assert errors[-1] < 1e-4


@pytest.mark.slow
def test_forced_membrane_second_order() -> None:
    errors = _errors("membrane-forced", [32, 64, 128])
    orders = _orders(errors)
    assert all(1.9 < p < 2.2 for p in orders), orders
    assert errors[-1] < 5e-4


def test_smoothed_pluck_second_order() -> None:
    errors = _errors("string-plucked-smooth", [200, 400, 800])
    orders = _orders(errors)
    assert all(1.9 < p < 2.1 for p in orders), orders


def test_kinked_pluck_first_order() -> None:
    """The triangle's kink: error ~ dx (its 1/n^2 spectrum meets the scheme's phase error)."""
    errors = _errors("string-plucked", [100, 200, 400])
    orders = _orders(errors)
    assert all(0.9 < p < 1.2 for p in orders), orders


def test_wrong_exact_solution_would_be_caught() -> None:
    """Against a slightly wrong reference (c off by 1%) the error stalls instead of falling."""
    problem = make_problem("string-forced")
    wrong = exact_solution(make_problem("string-forced", {"c": "10.1"}))
    t = np.linspace(0.0, 1.0, 11)
    errors = []
    for n in (50, 100, 200):
        fd = solve_fd(problem, n, t)
        reference = wrong.grid(*fd.axes, t)
        errors.append(float(np.linalg.norm(fd.u - reference) / np.linalg.norm(reference)))
    assert min(_orders(errors)) < 0.5


def test_time_step_respects_cfl_and_output_times() -> None:
    problem = make_problem("membrane-forced")
    t = np.linspace(0.0, 1.0, 6)
    fd = solve_fd(problem, 20, t, cfl=0.5)
    assert problem.c * fd.dt / (1 / 20) <= 0.5 / math.sqrt(2) + 1e-12
    assert round(0.2 / fd.dt) * fd.dt == pytest.approx(0.2)
    assert fd.u.shape == (21, 21, 6) and np.all(fd.u[..., 0] == 0.0)
    assert np.all(fd.u[0] == 0.0) and np.all(fd.u[:, -1] == 0.0)


@pytest.mark.parametrize(
    ("cells", "t", "cfl", "fragment"),
    [
        (1, [0.0, 1.0], 0.5, "n_cells"),
        (10, [0.1, 1.0], 0.5, "start at 0"),
        (10, [0.0, 0.1, 0.5], 0.5, "evenly spaced"),
        (10, [0.0, 1.0], 1.5, "cfl"),
    ],
)
def test_bad_arguments(cells: int, t: list[float], cfl: float, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        solve_fd(make_problem("string-forced"), cells, t, cfl=cfl)
