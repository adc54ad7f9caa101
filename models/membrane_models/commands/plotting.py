"""Figures for `membrane exact --plot`: a space-time map (string), snapshots (membrane).

matplotlib (the `plot` extra) is imported when a figure is drawn, with the file-only Agg backend.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["plot_solution", "solution_figure"]

FloatArray = NDArray[np.float64]

_SNAPSHOTS = 4


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_solution(path: Path, title: str, axes: dict[str, FloatArray], u: FloatArray) -> None:
    """Draw ``u`` on its grid to ``path`` (image format from its suffix, e.g. .png); the
    arguments are ``solution_figure``'s."""
    figure = solution_figure(title, axes, u)
    figure.savefig(path, dpi=110)
    _pyplot().close(figure)


def solution_figure(title: str, axes: dict[str, FloatArray], u: FloatArray) -> Any:
    """``u`` on its grid as a matplotlib Figure: a string's (x, t) map, or a membrane's (x, y)
    snapshots.

    Args:
        title: figure title (the problem name).
        axes: the coordinate arrays by name: x, t or x, y, t.
        u: values shaped (nx, nt) or (nx, ny, nt).
    """
    plt = _pyplot()
    limit = float(np.abs(u).max()) or 1.0
    if u.ndim == 2:
        # x across, t up, like `membrane evaluate --plot` and the membrane's (x, y) panels.
        figure, axis = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
        image = axis.pcolormesh(
            axes["x"], axes["t"], u.T, cmap="RdBu_r", vmin=-limit, vmax=limit, shading="auto"
        )
        axis.set_xlabel("x")
        axis.set_ylabel("t")
        figure.colorbar(image, ax=axis, label="u")
    else:
        t = axes["t"]
        # Quarter points of the time axis (t = 0 is the resting state, not worth a panel).
        fractions = np.arange(1, _SNAPSHOTS + 1) / _SNAPSHOTS
        picks = np.unique((fractions * (t.size - 1)).round().astype(int))
        figure, grid = plt.subplots(
            1, picks.size, figsize=(3.2 * picks.size, 3.4), constrained_layout=True
        )
        for axis, index in zip(np.atleast_1d(grid), picks, strict=True):
            image = axis.pcolormesh(
                axes["x"],
                axes["y"],
                u[:, :, index].T,
                cmap="RdBu_r",
                vmin=-limit,
                vmax=limit,
                shading="auto",
            )
            axis.set_title(f"t = {t[index]:.3g}")
            axis.set_xlabel("x")
            axis.set_ylabel("y")
            axis.set_aspect("equal")
        figure.colorbar(image, ax=np.atleast_1d(grid).tolist(), label="z")
    figure.suptitle(title)
    return figure
