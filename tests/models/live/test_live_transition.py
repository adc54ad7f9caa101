"""The exact per-mode transition: closed forms, block exponential and analytic responses."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from membrane_models.live.transition import _damped, _expm, _undamped, transition


def test_undamped_closed_forms_match_the_block_exponential() -> None:
    x = np.logspace(-6, 2, 81)
    closed = _undamped(x)
    block = _damped(x, 0.0)  # expm of the same generator with zeta = 0
    for mine, theirs in zip(closed, block, strict=True):
        scale = np.maximum(1.0, np.abs(theirs))
        assert np.max(np.abs(mine - theirs) / scale) < 1e-11


def _x_minus_sin_exact(x: float) -> float:
    """x - sin x in exact rational arithmetic (its Taylor series, 25 terms)."""
    value, total = Fraction(x), Fraction(0)
    for k in range(1, 26):
        term = value ** (2 * k + 1) / math.factorial(2 * k + 1)
        total += term if k % 2 == 1 else -term
    return float(total)


def test_x_minus_sin_keeps_its_relative_accuracy_for_tiny_steps() -> None:
    x = np.array([1e-8, 1e-4, 0.05, 0.19, 0.21, 1.0])
    eq = _undamped(x)[6]
    exact = np.array([_x_minus_sin_exact(float(v)) for v in x])
    relative = np.abs(eq / exact - 1.0)
    assert relative[:4].max() < 1e-14  # the series, below x = 0.2
    assert relative[4:].max() < 1e-13  # the difference, whose cancellation is mild above it
    # and 1 - cos by its half-angle form: q responds with (1 - cos x) / w^2 even at x = 1e-8
    assert _undamped(np.array([1e-8]))[4][0] == pytest.approx(0.5e-16, rel=1e-12)


@pytest.mark.parametrize("dt", [1e-4, 0.01, 0.3, 7.0])
def test_held_force_from_rest_is_exact_at_any_step(dt: float) -> None:
    w = np.array([0.5, 3.0, 40.0, 900.0])
    tr = transition(w, 0.0, dt)
    q, v = np.zeros(4), np.zeros(4)
    p = 2.5
    for _ in range(13):
        q, v = tr.qq * q + tr.qv * v + tr.zoh_q * p, tr.vq * q + tr.vv * v + tr.zoh_v * p
    t = 13 * dt
    exact = p / w**2 * 2.0 * np.sin(0.5 * w * t) ** 2  # 1 - cos, without its cancellation
    np.testing.assert_allclose(q, exact, rtol=1e-10)
    np.testing.assert_allclose(v, p / w * np.sin(w * t), rtol=1e-10, atol=1e-14)


def test_first_order_hold_follows_a_ramp_exactly() -> None:
    w, beta, dt = np.array([2.0, 31.0]), 3.0, 0.037
    tr = transition(w, 0.0, dt)
    q, v = np.zeros(2), np.zeros(2)
    for k in range(20):
        p0, p1 = beta * k * dt, beta * (k + 1) * dt
        q, v = (
            tr.qq * q + tr.qv * v + tr.foh0_q * p0 + tr.foh1_q * p1,
            tr.vq * q + tr.vv * v + tr.foh0_v * p0 + tr.foh1_v * p1,
        )
    t = 20 * dt
    np.testing.assert_allclose(q, beta / w**2 * (t - np.sin(w * t) / w), rtol=1e-11)
    np.testing.assert_allclose(v, beta / w**2 * (1.0 - np.cos(w * t)), rtol=1e-11)


@pytest.mark.parametrize("zeta", [0.05, 1.0, 2.5])
def test_damped_step_matches_an_ode_solver(zeta: float) -> None:
    w, dt, q0, v0, p0, p1 = 7.0, 0.3, 0.2, -1.1, 1.0, 3.0

    def rhs(t: float, y: np.ndarray) -> list[float]:
        p = p0 + (p1 - p0) * t / dt
        return [y[1], p - 2.0 * zeta * w * y[1] - w**2 * y[0]]

    solved = solve_ivp(rhs, (0.0, dt), [q0, v0], rtol=1e-12, atol=1e-14, method="DOP853")
    tr = transition(np.array([w]), zeta, dt)
    q = tr.qq * q0 + tr.qv * v0 + tr.foh0_q * p0 + tr.foh1_q * p1
    v = tr.vq * q0 + tr.vv * v0 + tr.foh0_v * p0 + tr.foh1_v * p1
    assert q[0] == pytest.approx(solved.y[0, -1], rel=1e-9)
    assert v[0] == pytest.approx(solved.y[1, -1], rel=1e-9)
    held = tr.qq * q0 + tr.qv * v0 + tr.zoh_q * p1
    assert held[0] == pytest.approx(solve_ivp(
        lambda t, y: [y[1], p1 - 2 * zeta * w * y[1] - w**2 * y[0]],
        (0.0, dt), [q0, v0], rtol=1e-12, atol=1e-14, method="DOP853",
    ).y[0, -1], rel=1e-9)  # fmt: skip


def test_transition_is_stable_at_any_step() -> None:
    w = np.array([1.0, 1e3])
    for zeta, bound in ((0.0, 1.0 + 1e-12), (0.1, 1.0)):
        tr = transition(w, zeta, 1e4 / math.pi)  # thousands of periods in one step
        for k in range(2):
            matrix = np.array([[tr.qq[k], tr.qv[k] * w[k]], [tr.vq[k] / w[k], tr.vv[k]]])
            assert np.abs(np.linalg.eigvals(matrix)).max() <= bound


@pytest.mark.parametrize("zeta", [0.02, 0.5, 1.0, 2.5])
def test_the_batched_exponential_matches_scipys(zeta: float) -> None:
    """``_expm`` (numpy, so that it releases the GIL) against scipy.linalg.expm, one matrix at
    a time, from steps far below a mode's period to far above it: every entry to 1e-11 of
    max(1, |entry|), and the small ones (the ramp's x^3 / 6 at x = 1e-8) to 1e-11 relative."""
    x = np.logspace(-8, 3, 120)
    generator = np.zeros((4, 4))
    generator[0, 1], generator[1, 0], generator[1, 1] = 1.0, -1.0, -2.0 * zeta
    generator[1, 2], generator[2, 3] = 1.0, 1.0
    matrices = x[:, None, None] * generator
    mine = _expm(matrices)
    theirs = np.stack([scipy.linalg.expm(m) for m in matrices])
    assert np.max(np.abs(mine - theirs) / np.maximum(1.0, np.abs(theirs))) < 1e-11
    small = x < 1.0
    nonzero = np.abs(theirs[small]) > 1e-300
    relative = np.abs(mine[small] - theirs[small])[nonzero] / np.abs(theirs[small])[nonzero]
    assert relative.max() < 1e-11
