"""The problems: the study's defaults, overrides, and rejection of invalid parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from membrane_models.problems import (
    PROBLEMS,
    InvalidProblem,
    MembraneForced,
    StringForced,
    StringPlucked,
    make_problem,
    time_bump,
)


def test_registry_names() -> None:
    assert set(PROBLEMS) == {
        "string-forced",
        "string-plucked",
        "string-plucked-smooth",
        "membrane-forced",
        "string-kirchhoff",
    }


def test_study_defaults() -> None:
    string = make_problem("string-forced")
    assert isinstance(string, StringForced)
    assert (string.c, string.x0, string.h, string.a, string.k, string.t_end) == (
        10.0,
        0.8,
        1.0,
        8.9,
        400.0,
        1.0,
    )
    membrane = make_problem("membrane-forced")
    assert isinstance(membrane, MembraneForced)
    assert (membrane.c, membrane.x0, membrane.y0, membrane.t_end) == (5.0, 0.8, 0.5, 1.0)
    assert membrane.spatial_dims == 2 and membrane.axes == ("x", "y", "t")


def test_plucked_defaults_and_smooth_variant() -> None:
    kinked = make_problem("string-plucked")
    smooth = make_problem("string-plucked-smooth")
    assert isinstance(kinked, StringPlucked) and isinstance(smooth, StringPlucked)
    assert (kinked.c, kinked.t_end, kinked.height, kinked.x0) == (1.0, 2.0, 0.05, 0.3)
    assert kinked.smoothing == 0.0
    assert smooth.smoothing == 0.02
    np.testing.assert_allclose(kinked.triangle([0.0, 0.3, 1.0]), [0.0, 0.05, 0.0])


def test_overrides_are_case_insensitive_and_typed() -> None:
    problem = make_problem("string-forced", {"C": "8", "x0": "0.7"})
    assert isinstance(problem, StringForced)
    assert problem.c == 8.0 and problem.x0 == 0.7
    assert problem.parameters()["c"] == 8.0


@pytest.mark.parametrize(
    ("name", "overrides", "fragment"),
    [
        ("string-forced", {"C": "-1"}, "c must be > 0"),
        ("string-forced", {"c": "0"}, "c must be > 0"),
        ("membrane-forced", {"C": "nan"}, "finite"),
        ("membrane-forced", {"y0": "1.0"}, "y0 must lie inside"),
        ("string-forced", {"x0": "-0.1"}, "x0 must lie inside"),
        ("string-forced", {"a": "0.5"}, "a must be >= 1"),
        ("string-forced", {"k": "0"}, "k must be > 0"),
        ("string-plucked", {"smoothing": "-0.1"}, "smoothing must be >= 0"),
        ("string-plucked", {"t_end": "inf"}, "finite"),
        ("string-forced", {"nope": "1"}, "no parameter 'nope'"),
        ("string-forced", {"c": "ten"}, "must be a number"),
        ("no-such-problem", {}, "unknown problem"),
    ],
)
def test_invalid_values_are_rejected(name: str, overrides: dict[str, str], fragment: str) -> None:
    with pytest.raises(InvalidProblem, match=fragment):
        make_problem(name, overrides)


def test_invalid_problem_is_a_value_error() -> None:
    assert issubclass(InvalidProblem, ValueError)


@pytest.mark.parametrize("a", [1.0, 2.0, 8.9, 50.0])
def test_time_bump_peaks_at_four_and_vanishes_outside(a: float) -> None:
    t = np.linspace(-0.5, 1.5, 2001)
    g = time_bump(t, a)
    assert np.all(np.isfinite(g))
    assert g.max() == pytest.approx(4.0, rel=1e-12)
    assert float(time_bump(0.5, a)) == pytest.approx(4.0, rel=1e-12)
    assert np.all(g[(t < 0.0) | (t > 1.0)] == 0.0)


def test_time_bump_formula() -> None:
    t = np.array([0.1, 0.3, 0.77])
    a = 8.9
    expected = 4.0**a * t ** (a - 1) * (1 - t) ** (a - 1)
    np.testing.assert_allclose(time_bump(t, a), expected, rtol=1e-13)
    assert math.isclose(float(time_bump(1.0, 1.0)), 4.0)


def test_forcing_is_profile_times_bump() -> None:
    string = make_problem("string-forced")
    assert isinstance(string, StringForced)
    assert float(string.forcing(0.8, 0.5)) == pytest.approx(-4.0)
    membrane = make_problem("membrane-forced")
    assert isinstance(membrane, MembraneForced)
    assert float(membrane.forcing(0.8, 0.5, 0.5)) == pytest.approx(-4.0)
    assert float(membrane.forcing(0.8, 0.5, 1.2)) == 0.0
