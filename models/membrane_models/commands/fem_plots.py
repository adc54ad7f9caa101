"""Figures for `membrane fem ... --plot`: a deflection map, mode shapes, a time history.

matplotlib (the `plot` extra) is imported when a figure is drawn, with the file-only Agg
backend. Coordinates are drawn in mm, deflections in mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["MAX_PANELS", "plot_deflection", "plot_history", "plot_modes"]

FloatArray = NDArray[np.float64]
MAX_PANELS = 9  # mode shapes drawn: a grid of up to 3 x 3


def plot_deflection(path: Path, mesh: Any, w: FloatArray, at: FloatArray, title: str) -> None:
    """The deflection ``w`` (m) at the mesh's vertices as a colour map, the load point marked."""
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(6.4, 5.2), constrained_layout=True)
    image = _field(axis, mesh, w * 1e3)
    axis.plot(at[0] * 1e3, at[1] * 1e3, "k+", markersize=12)
    axis.set_title(title)
    figure.colorbar(image, ax=axis, label="w (mm)")
    _save(plt, figure, path)


def plot_modes(path: Path, mesh: Any, shapes: FloatArray, frequencies: Sequence[float]) -> None:
    """The first mode shapes (vertex values, ``(vertices, modes)``), one panel each."""
    plt = _pyplot()
    count = min(MAX_PANELS, shapes.shape[1])
    columns = min(3, count)
    rows = math.ceil(count / columns)
    figure, axes = plt.subplots(
        rows, columns, figsize=(3.2 * columns, 3.0 * rows), constrained_layout=True, squeeze=False
    )
    for index, axis in enumerate(axes.flat):
        if index >= count:
            axis.set_visible(False)
            continue
        shape = shapes[:, index]
        _field(axis, mesh, shape / (np.abs(shape).max() or 1.0), symmetric=True)
        axis.set_title(f"mode {index + 1}: {frequencies[index]:.4g} Hz", fontsize=9)
        axis.set_axis_off()
    _save(plt, figure, path)


def plot_history(path: Path, t: FloatArray, w: FloatArray, static: float, title: str) -> None:
    """The deflection under the load (m) against time (s), with the static deflection."""
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(7, 4), constrained_layout=True)
    axis.plot(t * 1e3, w * 1e3, label="live engine")
    axis.axhline(static * 1e3, color="k", linestyle="--", linewidth=1, label="static")
    axis.set_xlabel("t (ms)")
    axis.set_ylabel("w under the load (mm)")
    axis.set_title(title)
    axis.legend(loc="lower right")
    _save(plt, figure, path)


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _field(axis: Any, mesh: Any, values: FloatArray, symmetric: bool = False) -> Any:
    """``values`` at the vertices of ``mesh`` (m) on ``axis``, x and y in mm, equal aspect."""
    x, y = mesh.p[0] * 1e3, mesh.p[1] * 1e3
    limit = float(np.abs(values).max()) or 1.0
    scale = {"vmin": -limit, "vmax": limit} if symmetric else {}
    image = axis.tripcolor(
        x,
        y,
        mesh.t.T,
        values,
        shading="gouraud",
        cmap="RdBu_r" if symmetric else "viridis",
        **scale,
    )
    axis.set_aspect("equal")
    axis.set_xlabel("x (mm)")
    axis.set_ylabel("y (mm)")
    return image


def _save(plt: Any, figure: Any, path: Path) -> None:
    figure.savefig(path, dpi=110)
    plt.close(figure)
