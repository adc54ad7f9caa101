"""LiveLimits: a live scene's bounds from its describe, and untrusted probes and loads checked
against them with short messages (the browser bridge's page input goes through it)."""

from __future__ import annotations

from typing import Any

import pytest

from membrane_client.live_limits import (
    DEFAULT_MAX_DEPTH,
    DEFAULT_MAX_RADIUS,
    InvalidInput,
    LiveLimits,
)
from membrane_client.session import Load, Probe
from membrane_errors import UserError

LIVE = {"max_probes": 8, "max_loads": 64, "min_radius": 0.04, "max_radius": 10.0,
        "max_depth": 1000.0, "max_force": 1e6}  # fmt: skip


def test_bounds_come_from_the_live_map() -> None:
    limits = LiveLimits.from_live({**LIVE, "max_depth": 0.5, "max_probes": 3}, dims=2)
    assert limits == LiveLimits(2, max_probes=3, min_radius=0.04, max_depth=0.5)


@pytest.mark.parametrize("bad", [None, "1", True, float("nan"), float("inf"), -1.0, [1], 10**400])
def test_a_missing_or_unusable_bound_keeps_the_default(bad: Any) -> None:
    live = {"min_radius": 0.04} if bad is None else {"min_radius": 0.04, "max_depth": bad}
    limits = LiveLimits.from_live(live, dims=1)
    assert limits.max_depth == DEFAULT_MAX_DEPTH and limits.max_radius == DEFAULT_MAX_RADIUS


def test_a_good_probe_is_a_probe_of_floats() -> None:
    limits = LiveLimits.from_live(LIVE, dims=2)
    probe = limits.check_probe([0.5, 1], 0.01, 0.05)
    assert probe == Probe((0.5, 1.0), 0.01, 0.05) and type(probe.at[1]) is float
    assert LiveLimits.from_live(LIVE, dims=1).check_probe((0.25,), 0, 0.05).depth == 0.0


@pytest.mark.parametrize(
    ("at", "depth", "radius", "says"),
    [
        ([0.5], 0.01, 0.05, "probe at must be 2 numbers, got 1 value"),
        ([0.5, 0.5, 0.5], 0.01, 0.05, "got 3 values"),
        ([0.1] * 7000, 0.01, 0.05, "got 7000 values"),
        ("0.5,0.5", 0.01, 0.05, "probe at must be 2 numbers, got '0.5,0.5'"),
        ({"x": 1, "y": 2}, 0.01, 0.05, "got a map of 2"),
        ([0.5, True], 0.01, 0.05, "probe at must be a number, got a bool"),
        ([0.5, None], 0.01, 0.05, "got null"),
        ([0.5, float("nan")], 0.01, 0.05, "must be finite"),
        ([0.5, 10**400], 0.01, 0.05, "a huge integer"),
        ([0.5, 0.5], True, 0.05, "probe depth must be a number, got a bool (True)"),
        ([0.5, 0.5], "0.01", 0.05, "probe depth must be a number, got a string '0.01'"),
        ([0.5, 0.5], -1e4, 0.05, "probe depth must be in [-1000, 1000]"),
        ([0.5, 0.5], 1e308, 0.05, "probe depth must be in [-1000, 1000], got 1e+308"),
        ([0.5, 0.5], float("inf"), 0.05, "probe depth must be finite"),
        ([0.5, 0.5], 0.01, 1e-4, "probe radius must be in [0.04, 10], got 0.0001"),
        ([0.5, 0.5], 0.01, 1e-310, "got 1e-310"),
        ([0.5, 0.5], 0.01, 1e308, "got 1e+308"),
        ([0.5, 0.5], 0.01, -0.05, "probe radius must be in"),
    ],
)
def test_a_bad_probe_is_refused_in_one_short_line(
    at: Any, depth: Any, radius: Any, says: str
) -> None:
    limits = LiveLimits.from_live(LIVE, dims=2)
    with pytest.raises(InvalidInput) as caught:
        limits.check_probe(at, depth, radius)
    message = str(caught.value)
    assert says in message and "\n" not in message and len(message) <= 120, message
    assert isinstance(caught.value, UserError)


def test_a_long_value_is_quoted_at_most_64_characters() -> None:
    limits = LiveLimits.from_live(LIVE, dims=2)
    with pytest.raises(InvalidInput) as caught:
        limits.check_probe([0.5, "x" * 10_000], 0.01, 0.05)
    assert "x" * 64 in str(caught.value) and "x" * 65 not in str(caught.value)
    assert len(str(caught.value)) < 160


def test_a_callers_own_depth_bound_is_the_tighter_one() -> None:
    limits = LiveLimits.from_live(LIVE, dims=2)
    assert limits.check_probe([0.5, 0.5], 0.02, 0.05, max_depth=0.02).depth == 0.02
    with pytest.raises(InvalidInput, match=r"in \[0, 0.02\], got 1"):
        limits.check_probe([0.5, 0.5], 1.0, 0.05, max_depth=0.02, min_depth=0.0)
    tight = LiveLimits.from_live({**LIVE, "max_depth": 0.01}, dims=2)
    with pytest.raises(InvalidInput, match=r"in \[-0.01, 0.01\]"):
        tight.check_probe([0.5, 0.5], 0.015, 0.05, max_depth=0.02)


def test_a_depth_is_signed_a_tip_above_the_rest_surface_is_a_probe_too() -> None:
    limits = LiveLimits.from_live(LIVE, dims=2)
    assert limits.check_probe([0.5, 0.5], -1e-3, 0.05).depth == -1e-3
    with pytest.raises(InvalidInput, match=r"in \[0, 1000\], got -0.001"):
        limits.check_probe([0.5, 0.5], -1e-3, 0.05, min_depth=0.0)  # a caller that only presses


def test_a_point_probe_only_on_a_string() -> None:
    string = LiveLimits.from_live({"min_radius": 0.0}, dims=1)
    assert string.check_probe([0.5], 0.01, 0).radius == 0.0
    membrane = LiveLimits.from_live({"min_radius": 0.0}, dims=2)
    with pytest.raises(InvalidInput, match="> 0 on a membrane"):
        membrane.check_probe([0.5, 0.5], 0.01, 0.0)


def test_loads_and_counts() -> None:
    limits = LiveLimits.from_live(LIVE, dims=2)
    assert limits.check_load([0.5, 0.5], -2, 0.05) == Load((0.5, 0.5), -2.0, 0.05)
    with pytest.raises(InvalidInput, match="at most 1e"):
        limits.check_load([0.5, 0.5], 1e7, 0.05)
    with pytest.raises(InvalidInput, match="unit domain"):
        limits.check_load([1.5, 0.5], 1.0, 0.05)
    limits.check_count(probes=8, loads=64)
    with pytest.raises(InvalidInput, match="at most 8 probes"):
        limits.check_count(probes=9)
    with pytest.raises(InvalidInput, match="at most 64 loads"):
        limits.check_count(loads=65)


def test_only_strings_and_membranes() -> None:
    with pytest.raises(InvalidInput, match="1 or 2 dimensions"):
        LiveLimits.from_live(LIVE, dims=3)


def test_a_point_probe_is_taken_where_the_plates_tables_carry_point_forces() -> None:
    """skin-patch's live map says radii [0.0]: its tables carry point forces, finite on a
    plate. Without that, a point on a 2-D scene stays refused (singular on a membrane)."""
    plate = LiveLimits.from_live({**LIVE, "min_radius": 0.0, "radii": [0.0]}, dims=2)
    assert plate.point_forces and plate.check_probe([0.02, 0.02], 0.001, 0.0).radius == 0.0
    for live in ({**LIVE, "min_radius": 0.0}, {**LIVE, "min_radius": 0.0, "radii": [0.002]}):
        membrane = LiveLimits.from_live(live, dims=2)
        with pytest.raises(InvalidInput, match="a point is singular"):
            membrane.check_probe([0.5, 0.5], 0.01, 0.0)
