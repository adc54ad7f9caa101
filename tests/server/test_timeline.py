"""Time snapping and out-of-domain policies, in float64, at ordinary and extreme times."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from membrane_client.protocol import Domain
from membrane_server.timeline import OutOfDomain, Timeline

GRID = Timeline(dt=0.01, last_step=100)


def test_grid_times_are_served_exactly() -> None:
    for k in range(1000):
        t = (k % 101) * 0.01
        sample = GRID.resolve(t)
        assert sample.step == k % 101
        assert sample.t == t
        assert sample.weight == 0.0
        assert sample.domain is Domain.INSIDE


def test_nearest_rounds_to_the_closest_step() -> None:
    assert GRID.resolve(0.2549).step == 25
    assert GRID.resolve(0.2551).step == 26
    assert GRID.resolve(0.0049).step == 0


def test_start_offset_shifts_the_grid() -> None:
    timeline = Timeline(dt=0.01, last_step=100, start_offset=5.0)
    sample = timeline.resolve(5.25)
    assert (sample.step, sample.t) == (25, 5.0 + 25 * 0.01)
    assert timeline.model_time(25) == 25 * 0.01
    assert timeline.resolve(4.0).step == 0  # before the start: held at the first frame


@pytest.mark.parametrize("t", [-1e-12, 1e-12, -0.0, 0.0])
def test_times_at_zero_snap_to_step_zero(t: float) -> None:
    sample = GRID.resolve(t)
    assert (sample.step, sample.domain) == (0, Domain.INSIDE)


@pytest.mark.parametrize(("policy", "domain"), [("hold", Domain.HELD), ("clamp", Domain.CLAMPED)])
@pytest.mark.parametrize("t", [1.006, 3.0, 1e9, 1e300])
def test_past_the_end_serves_the_last_step(policy: str, domain: Domain, t: float) -> None:
    timeline = Timeline(dt=0.01, last_step=100, policy=policy)  # type: ignore[arg-type]
    sample = timeline.resolve(t)
    assert (sample.step, sample.t, sample.domain) == (100, 100 * 0.01, domain)


@pytest.mark.parametrize("t", [-0.006, -1.0, -1e9])
def test_before_the_start_serves_the_first_step(t: float) -> None:
    sample = Timeline(dt=0.01, last_step=100, policy="clamp").resolve(t)
    assert (sample.step, sample.t, sample.domain) == (0, 0.0, Domain.CLAMPED)


@pytest.mark.parametrize("t", [1.006, 1e9, -0.006])
def test_error_policy_refuses_outside_times(t: float) -> None:
    with pytest.raises(OutOfDomain, match="outside the scene's time domain"):
        Timeline(dt=0.01, last_step=100, policy="error").resolve(t)


def test_last_step_is_inside_under_error_policy() -> None:
    sample = Timeline(dt=0.01, last_step=100, policy="error").resolve(1.0)
    assert (sample.step, sample.domain) == (100, Domain.INSIDE)


@pytest.mark.parametrize("t", [math.nan, math.inf, -math.inf])
def test_non_finite_times_are_refused(t: float) -> None:
    with pytest.raises(ValueError, match="finite"):
        GRID.resolve(t)


def test_huge_step_counts_keep_float64_precision() -> None:
    # With dt = 1e-3 and 1e9 steps, float32 could not tell neighbouring steps apart.
    timeline = Timeline(dt=1e-3, last_step=10**9)
    sample = timeline.resolve(999_999.999)
    assert sample.step == 999_999_999


def test_linear_snapping_interpolates_between_steps() -> None:
    timeline = Timeline(dt=0.01, last_step=100, snapping="linear")
    sample = timeline.resolve(0.2525)
    assert sample.step == 25
    assert sample.t == 0.2525
    assert sample.weight == pytest.approx(0.25, abs=1e-9)
    last = timeline.resolve(1.0)
    assert (last.step, last.weight) == (100, 0.0)
    past = timeline.resolve(1.001)
    assert (past.step, past.weight, past.domain) == (100, 0.0, Domain.HELD)


@given(st.floats(min_value=-1e12, max_value=1e12, allow_nan=False))
def test_every_finite_time_gets_a_valid_step(t: float) -> None:
    sample = GRID.resolve(t)
    assert 0 <= sample.step <= 100
    assert sample.t == GRID.step_time(sample.step)
    if 0.0 <= t <= 1.0:
        assert abs(sample.t - t) <= 0.005 + 1e-12
