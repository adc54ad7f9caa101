"""Plot orientation: every space-time map puts x across and t up; membrane maps x across, y up.

The figures are built (matplotlib, Agg) and inspected: axis labels, and which array index runs
along which screen axis, using data that differs along each axis.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from membrane_models.artifacts.evaluate import ErrorReport, comparison_figure
from membrane_models.commands.plotting import solution_figure


def _report(exact: np.ndarray, axes: list[np.ndarray]) -> ErrorReport:
    return ErrorReport(
        model="m", problem="p", relative_l2=0.0, max_abs=0.0, axes=axes,
        predicted=exact + 1e-3, exact=exact,
    )  # fmt: skip


def test_evaluate_plot_of_a_string_puts_x_across_and_t_up() -> None:
    x, t = np.linspace(0, 1, 5), np.linspace(0, 2, 3)
    exact = x[:, None] * 10 + t[None, :]  # [i, k] = 10 x_i + t_k: distinct along each axis
    figure = comparison_figure(_report(exact, [x, t]))
    panels = [a for a in figure.axes if a.images]  # predicted, exact, error; not colour bars
    assert [a.get_title() for a in panels] == ["predicted", "exact", "error"]
    for axis in panels:
        assert (axis.get_xlabel(), axis.get_ylabel()) == ("x", "t")
    image = panels[1].images[0]
    shown = np.asarray(image.get_array())
    assert shown.shape == (t.size, x.size)  # rows (up the screen) are times
    np.testing.assert_allclose(shown, exact.T)
    assert list(image.get_extent()) == [0.0, 1.0, 0.0, 2.0]


def test_evaluate_plot_of_a_membrane_puts_x_across_and_y_up() -> None:
    x, y, t = np.linspace(0, 1, 4), np.linspace(0, 1, 3), np.linspace(0, 1, 2)
    exact = x[:, None, None] * 10 + y[None, :, None] + t[None, None, :] * 100
    figure = comparison_figure(_report(exact, [x, y, t]))
    exact_panel = next(a for a in figure.axes if a.get_title().startswith("exact"))
    assert (exact_panel.get_xlabel(), exact_panel.get_ylabel()) == ("x", "y")
    np.testing.assert_allclose(np.asarray(exact_panel.images[0].get_array()), exact[:, :, 1].T)


def test_exact_plot_of_a_string_puts_x_across_and_t_up() -> None:
    x, t = np.linspace(0, 1, 5), np.linspace(0, 2, 3)
    u = x[:, None] * 10 + t[None, :]
    figure = solution_figure("string", {"x": x, "t": t}, u)
    axis = figure.axes[0]
    assert (axis.get_xlabel(), axis.get_ylabel()) == ("x", "t")
    mesh = axis.collections[0]
    np.testing.assert_allclose(np.asarray(mesh.get_array()).reshape(t.size, x.size), u.T)
