"""The Kirchhoff-Carrier string's modal solver: finite differences, energy, the linear limit."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.special import ellipj, ellipk

from membrane_models.checks.kirchhoff_fd import solve_kirchhoff_fd
from membrane_models.exact.kirchhoff_carrier import (
    KirchhoffString,
    frequency_ratio,
    solve_kirchhoff,
)
from membrane_models.exact.plucked import PluckedDAlembert, pluck_extension
from membrane_models.problems import InvalidProblem, StringPlucked, make_problem
from membrane_models.problems.string_shapes import pluck

STRING = KirchhoffString(c=1.0, k=100.0)


def _smooth_pluck(height: float, apex: float, sigma: float) -> StringPlucked:
    overrides = {"height": str(height), "x0": str(apex), "smoothing": str(sigma)}
    problem = make_problem("string-plucked", overrides)
    assert isinstance(problem, StringPlucked)
    return problem


# A smoothed pluck with a velocity sin^3(pi x) = (3 sin(pi x) - sin(3 pi x)) / 4: both closed
# forms, sampled by the finite differences and expanded in sines for the modal solver.
PLUCK = _smooth_pluck(0.03, 0.3, 0.05)
SPEED = 0.1


def _modal_data(modes: int) -> tuple[np.ndarray, np.ndarray]:
    q0 = PLUCK.height * pluck(PLUCK.x0, modes, PLUCK.smoothing)
    p0 = np.zeros(modes)
    p0[0], p0[2] = 0.75 * SPEED, -0.25 * SPEED
    return q0, p0


def _fd_error(string: KirchhoffString, n_cells: int, t: np.ndarray) -> float:
    fd = solve_kirchhoff_fd(
        string,
        lambda x: pluck_extension(PLUCK, x),
        lambda x: SPEED * np.sin(np.pi * x) ** 3,
        n_cells,
        t,
    )
    q0, p0 = _modal_data(64)  # the tail beyond mode 64 is below exp(-48)
    u, _ = solve_kirchhoff(STRING, q0, p0, t).at_points(fd.axes[0])
    return float(np.linalg.norm(fd.u - u.T) / np.linalg.norm(u))


def test_finite_differences_converge_to_it_at_second_order() -> None:
    q0, p0 = _modal_data(64)
    assert float(STRING.nonlinearity(q0, p0)) > 0.5  # strongly nonlinear: tension x 1.5
    t = np.linspace(0.0, 1.0, 11)
    errors = [_fd_error(STRING, n, t) for n in (50, 100, 200)]
    orders = [math.log2(a / b) for a, b in itertools.pairwise(errors)]
    assert errors[-1] < 2e-4
    assert all(1.9 < order < 2.1 for order in orders), (errors, orders)
    # Against a string 1% stiffer the same refinement stalls: the test sees k.
    stiffer = KirchhoffString(c=1.0, k=101.0)
    wrong = [_fd_error(stiffer, n, t) for n in (100, 200)]
    assert wrong[0] / wrong[1] < 1.5


def _at_nonlinearity(q0: np.ndarray, p0: np.ndarray, eps: float) -> tuple[np.ndarray, ...]:
    """(a q0, a p0) with k S* / c^2 = eps (c = 1): a quadratic in a^2."""
    linear = 0.5 * float(STRING.stretch(q0)) + 0.25 * float(np.sum(p0**2))
    q0, p0 = q0 / math.sqrt(linear), p0 / math.sqrt(linear)
    quartic = 0.25 * STRING.k * float(STRING.stretch(q0)) ** 2
    target = (2.0 * eps + eps**2) / (4.0 * STRING.k)
    a2 = 2.0 * target / (1.0 + math.sqrt(1.0 + 4.0 * quartic * target))
    return q0 * math.sqrt(a2), p0 * math.sqrt(a2)


@pytest.mark.slow
@pytest.mark.parametrize("shape", ["noise", "kinked pluck"])
def test_energy_is_conserved_to_1e9_over_1000_steps(shape: str) -> None:
    rng = np.random.default_rng(3)
    n = np.arange(1, 129)
    if shape == "noise":  # 16 modes, with a velocity
        q0 = np.where(n <= 16, rng.standard_normal(128), 0.0)
        p0 = np.where(n <= 16, rng.standard_normal(128), 0.0) * math.pi * n
    else:  # all 128 modes of the kinked triangle, struck at another point
        q0, p0 = pluck(0.3, 128), pluck(0.6, 128) * math.pi
    q0, p0 = _at_nonlinearity(q0, p0, 1.0)
    assert float(STRING.nonlinearity(q0, p0)) == pytest.approx(1.0, rel=1e-12)
    solution = solve_kirchhoff(STRING, q0, p0, np.arange(1001) * 0.01)
    energy = solution.energy()
    drift = np.max(np.abs(energy - energy[0])) / energy[0]
    assert drift < 1e-9
    # The stretch swings: the energy's parts trade, so its constancy is not a trivial one.
    stretch = solution.stretch()
    assert stretch.max() > 1.5 * stretch.min()


def test_tolerance_reaches_1e10_of_the_motion() -> None:
    q0, p0 = _modal_data(64)
    t = np.arange(201) * 0.01
    x = np.arange(1, 129) / 129
    u, u_t = solve_kirchhoff(STRING, q0, p0, t).at_points(x)
    fine, fine_t = solve_kirchhoff(STRING, q0, p0, t, rtol=2.5e-14).at_points(x)  # scipy's floor
    assert np.max(np.abs(u - fine)) <= 1e-10 * np.max(np.abs(fine))
    assert np.max(np.abs(u_t - fine_t)) <= 1e-10 * np.max(np.abs(fine_t))


def test_k0_is_the_exact_linear_string() -> None:
    problem = _smooth_pluck(0.05, 0.3, 0.02)
    linear = KirchhoffString(c=problem.c, k=0.0)
    q0 = problem.height * pluck(problem.x0, 160, problem.smoothing)  # tail below exp(-50)
    t = np.linspace(0.0, 2.0, 41)
    x = np.linspace(0.0, 1.0, 101)
    u, _ = solve_kirchhoff(linear, q0, np.zeros(160), t).at_points(x)
    exact = PluckedDAlembert(problem).at_points(x[:, None], t).T
    assert np.max(np.abs(u - exact)) <= 1e-10 * problem.height


@pytest.mark.parametrize("mode", [1, 3])
def test_one_mode_is_duffing_in_closed_form(mode: int) -> None:
    # From rest at amplitude A: q = A cn(W t | m), W^2 = w0^2 (1 + eps), m = eps / (2 (1 + eps)).
    eps = 1.0
    w0 = mode * math.pi * STRING.c
    amplitude = math.sqrt(2.0 * eps * STRING.c**2 / STRING.k) / (mode * math.pi)
    q0 = np.zeros(mode)
    q0[-1] = amplitude
    assert float(STRING.nonlinearity(q0, np.zeros(mode))) == pytest.approx(eps, rel=1e-12)
    t = np.linspace(0.0, 4.0 / mode, 401)
    q = solve_kirchhoff(STRING, q0, np.zeros(mode), t).q[:, -1]
    big_w, m = w0 * math.sqrt(1.0 + eps), eps / (2.0 * (1.0 + eps))
    cn = ellipj(big_w * t, m)[1]
    np.testing.assert_allclose(q, amplitude * cn, rtol=0.0, atol=1e-10 * amplitude)
    period = 4.0 * float(ellipk(m)) / big_w
    assert float(frequency_ratio(eps)) == pytest.approx(2.0 * math.pi / period / w0, rel=1e-14)


def test_frequency_ratio_limits() -> None:
    # Lindstedt-Poincare (beta A^2 = w0^2 eps): w / w0 = 1 + 3 eps / 8 - 21 eps^2 / 256 + ...
    small = 1e-3
    expected = 1.0 + 3.0 * small / 8.0 - 21.0 * small**2 / 256.0
    assert float(frequency_ratio(small)) == pytest.approx(expected, abs=1e-9)
    assert float(frequency_ratio(0.0)) == 1.0
    assert float(frequency_ratio(1.0)) == pytest.approx(1.3178, abs=1e-4)


def test_bad_input_is_a_user_error() -> None:
    with pytest.raises(InvalidProblem, match="k must be"):
        KirchhoffString(k=-1.0)
    with pytest.raises(InvalidProblem, match="one length"):
        solve_kirchhoff(STRING, [1e-3], [0.0, 0.0], [0.0, 1.0])
    with pytest.raises(InvalidProblem, match="increasing"):
        solve_kirchhoff(STRING, [1e-3], [0.0], [1.0, 0.5])
    with pytest.raises(InvalidProblem, match="nonlinearity"):
        frequency_ratio(-0.5)


# -- the registered problem: string-kirchhoff, as `membrane exact` solves it --------------------


def test_string_kirchhoff_without_stretch_is_the_linear_plucked_string() -> None:
    """stretch = 0 is the linear wave equation from the same smoothed pluck: d'Alembert's closed
    form agrees to the 64-mode truncation of the pluck (its dropped tail, about 1e-9 here)."""
    from membrane_models.exact import exact_solution
    from membrane_models.problems import make_problem

    linear_k = exact_solution(make_problem("string-kirchhoff", {"stretch": "0"}))
    plucked = exact_solution(
        make_problem("string-plucked", {"smoothing": "0.02", "c": "1", "t_end": "2"})
    )
    x, t = np.linspace(0.0, 1.0, 101), np.linspace(0.0, 2.0, 41)
    a, b = linear_k.grid(x, t), plucked.grid(x, t)
    assert np.linalg.norm(a - b) / np.linalg.norm(b) < 1e-6
    assert linear_k.truncation_error == 0.0 and linear_k.n_modes == 64


def test_string_kirchhoff_stiffens_with_stretch_and_keeps_its_energy() -> None:
    """With stretch the tension grows with the amplitude: the string comes back sooner than
    the linear one's period 2 / c, and the Galerkin energy is conserved."""
    from membrane_models.exact import exact_solution
    from membrane_models.exact.kirchhoff_carrier import KirchhoffReference
    from membrane_models.problems import make_problem

    problem = make_problem("string-kirchhoff", {"stretch": "400"})
    solution = exact_solution(problem)
    assert isinstance(solution, KirchhoffReference)
    t = np.linspace(0.0, 2.0, 2001)
    q = solution.amplitudes(t)
    first = q[:, 0]
    returns = t[1:][(np.diff(np.sign(first - first[0])) != 0)]
    assert returns.size and returns[-1] < 2.0  # faster than the linear period
    string = solution.string
    energy = string.energy(q, np.gradient(q, t, axis=0))
    assert np.ptp(energy[50:-50]) / energy[50:-50].mean() < 1e-3  # finite differences of q
    # times in any order: the same state to the integrator's tolerance
    later_first = solution.amplitudes([1.0, 0.5])[1]
    np.testing.assert_allclose(later_first, solution.amplitudes([0.5])[0], rtol=0, atol=1e-12)
