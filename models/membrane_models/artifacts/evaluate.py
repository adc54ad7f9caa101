"""A model's error against the exact solution, through onnxruntime (no torch here).

The standard grid: string 101 x 101 points in (x, t), membrane 41 x 41 x 101 in (x, y, t),
uniform and including the domain's ends. Errors are relative L2 (over the whole space-time grid)
and max-abs. ``membrane export`` and ``membrane evaluate`` both call ``evaluate_model``, so the
manifest's figure and the printed one come from the same code.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.artifacts.manifest import Manifest
from membrane_models.exact import exact_solution
from membrane_models.problems import Problem, make_problem

__all__ = [
    "ErrorReport",
    "comparison_figure",
    "evaluate_model",
    "onnx_session",
    "plot_comparison",
    "reference_on_grid",
    "standard_axes",
]

FloatArray = NDArray[np.float64]

STRING_GRID = (101, 101)
MEMBRANE_GRID = (41, 41, 101)


def standard_axes(problem: Problem) -> list[FloatArray]:
    """The standard grid's axes, space first, then time on [0, t_end]."""
    shape = STRING_GRID if problem.spatial_dims == 1 else MEMBRANE_GRID
    axes = [np.linspace(0.0, 1.0, n) for n in shape[:-1]]
    axes.append(np.linspace(0.0, problem.t_end, shape[-1]))
    return axes


def reference_on_grid(problem: Problem) -> tuple[FloatArray, FloatArray]:
    """Grid points (n, d + 1) in 'ij' order and the exact solution there, flattened (n,)."""
    axes = standard_axes(problem)
    exact = exact_solution(problem).grid(*axes)
    mesh = np.meshgrid(*axes, indexing="ij")
    points = np.stack([m.reshape(-1) for m in mesh], axis=1)
    return points, exact.reshape(-1)


def onnx_session(path: Path) -> Any:
    """A single-threaded onnxruntime session (deterministic, and kind to a shared CPU)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


@dataclass
class ErrorReport:
    """A model's error on the standard grid, with the fields needed to plot it."""

    model: str
    problem: str
    relative_l2: float
    max_abs: float
    axes: list[FloatArray]
    predicted: FloatArray
    exact: FloatArray

    def grid_text(self) -> str:
        """The grid's shape as text, e.g. '101x101 (x, t)'."""
        names = ("x", "t") if len(self.axes) == 2 else ("x", "y", "t")
        return "x".join(str(len(a)) for a in self.axes) + f" ({', '.join(names)})"

    def to_dict(self) -> dict[str, Any]:
        """The figures as plain data (what the manifest's ``error`` holds)."""
        return {
            "relative_l2": self.relative_l2,
            "max_abs": self.max_abs,
            "grid": [len(a) for a in self.axes],
            "reference": "membrane_models.exact.exact_solution",
            "runtime": "onnxruntime",
        }


def evaluate_model(manifest: Manifest) -> ErrorReport:
    """Run the model's full graph on the standard grid and compare with the exact solution."""
    problem = make_problem(manifest.problem, {k: str(v) for k, v in manifest.parameters.items()})
    path = manifest.verify("full")
    points, exact = reference_on_grid(problem)
    session = onnx_session(path)
    name = manifest.graphs["full"].input
    predicted = session.run(None, {name: points.astype(np.float32)})[0][:, 0].astype(np.float64)
    shape = tuple(len(a) for a in standard_axes(problem))
    diff = predicted - exact
    return ErrorReport(
        model=manifest.name,
        problem=manifest.problem,
        relative_l2=float(np.linalg.norm(diff) / np.linalg.norm(exact)),
        max_abs=float(np.max(np.abs(diff))),
        axes=standard_axes(problem),
        predicted=predicted.reshape(shape),
        exact=exact.reshape(shape),
    )


def plot_comparison(report: ErrorReport, path: Path) -> None:
    """predicted | exact | error, drawn to ``path`` (see ``comparison_figure``)."""
    fig = comparison_figure(report)  # selects the file-only backend before pyplot is used
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110)
    plt.close(fig)


def comparison_figure(report: ErrorReport) -> Any:
    """predicted | exact | error as a matplotlib Figure: (x, t) maps for a string, x across and t
    up; for a membrane, (x, y) maps at the time of the largest displacement, x across and y up.
    The same orientation as `membrane exact --plot` and the demo's plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pred, exact = report.predicted, report.exact
    if pred.ndim == 3:
        k = int(np.argmax(np.max(np.abs(exact), axis=(0, 1))))
        pred, exact = pred[:, :, k], exact[:, :, k]
        extent = [0.0, 1.0, 0.0, 1.0]
        labels = ("x", "y", f"t = {report.axes[2][k]:.2f}")
    else:
        extent = [0.0, 1.0, 0.0, float(report.axes[1][-1])]
        labels = ("x", "t", "")
    # Arrays are indexed [x, second axis]; imshow puts the first index down the rows, so the
    # transpose puts x across.
    pred, exact = pred.T, exact.T
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    limit = float(np.max(np.abs(exact)))
    panels = (("predicted", pred, limit), ("exact", exact, limit), ("error", pred - exact, None))
    for ax, (title, data, lim) in zip(axes, panels, strict=True):
        vmax = lim if lim is not None else float(np.max(np.abs(data))) or 1.0
        image = ax.imshow(
            data, origin="lower", extent=extent, aspect="auto", cmap="RdBu_r", vmin=-vmax, vmax=vmax
        )
        ax.set_title(f"{title} {labels[2]}".strip())
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        fig.colorbar(image, ax=ax)
    fig.suptitle(
        f"{report.model}: relative L2 {report.relative_l2:.2e}, max abs {report.max_abs:.2e}"
    )
    return fig
