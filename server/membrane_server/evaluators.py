"""The four ways to answer a query, behind one interface: ``evaluator.frame(t) -> (n,) array``.

``t`` is model time (the network's t, step k at k * dt); the lattice is fixed at construction.

- ``network``: the model's full ONNX graph on the whole lattice, per query (general, slowest).
- ``separable``: for models whose output is sum_k A_k(x) B_k(t) + bias: A (n, r) from the
  ``space`` graph once at load; per query only the ``time`` graph (one row) and one mat-vec.
- ``table``: every frame of the scene's time grid computed at load (memory reported and capped);
  a lookup per query, linear interpolation between frames for times off the grid.
- ``exact``: the exact reference solution (membrane_models.exact), its grid frames computed
  once at load in float64 when they fit in the scene's table budget. Its working memory (the
  series' tables, the modes' values on the lattice) counts against that budget too: it is
  evaluated in a form that fits (see ``membrane_models.exact.forced``), or refused at load with the
  figure, and only what is left goes to frames.

Evaluators are stateless: a frame depends on t alone, so any number of clients share one.
Stateful answers (a session stepped under the loads and probes a client sends) are the other
interface, live engines (``membrane_models.live.LiveEngine``, served by ``live``), keyed by the
envelope's ``session``.
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from membrane_models.artifacts.manifest import Manifest
from membrane_models.budget import MemoryBudgetExceeded
from membrane_models.exact.solution import ExactSolution, PointFrames
from membrane_models.problems import Problem
from membrane_server.runtime import GraphRunner, load_graph
from membrane_server.scene import DEFAULT_TABLE_MAX_BYTES, Scene, SceneError
from membrane_server.source import ModelSource

__all__ = [
    "EXACT_WORKING_FLOOR_BYTES",
    "Evaluator",
    "ExactEvaluator",
    "FrameGrid",
    "NetworkEvaluator",
    "SeparableEvaluator",
    "TableEvaluator",
    "build_evaluator",
]

logger = logging.getLogger(__name__)

# Model times may exceed the trained domain's end by this much (float rounding of k * dt).
_TIME_SLACK = 1e-9
# The exact evaluator may always work in this much memory, even when a scene's table_max_bytes
# is smaller (which then only means: no precomputed frames).
EXACT_WORKING_FLOOR_BYTES = 16 * 2**20


class Evaluator(ABC):
    """Displacement on a fixed lattice as a function of model time.

    Args:
        points: (n, d) float64 lattice coordinates in problem units.
    """

    kind: ClassVar[str]

    def __init__(self, points: np.ndarray) -> None:
        self.points = np.array(points, dtype=np.float64, copy=True)
        if self.points.ndim != 2:
            raise ValueError(f"points must be (n, d), got shape {self.points.shape}")
        self.points.setflags(write=False)

    @property
    def n_points(self) -> int:
        """Number of lattice points."""
        return int(self.points.shape[0])

    @abstractmethod
    def frame(self, t: float) -> np.ndarray:
        """The (n,) displacement at model time ``t``."""

    def info(self) -> dict[str, Any]:
        """What ``describe`` reports about this evaluator (kind and its own figures)."""
        return {"kind": self.kind}

    @property
    def working_bytes(self) -> int:
        """Memory it needs besides precomputed frames, when counted against a scene's budget
        (the exact evaluator's; 0 for the network evaluators, whose caches are not counted)."""
        return 0


class NetworkEvaluator(Evaluator):
    """The full graph ((n, d + 1) -> (n, 1)) on the lattice for every query."""

    kind = "network"

    def __init__(self, full: GraphRunner, points: np.ndarray) -> None:
        super().__init__(points)
        self._full = full
        # The input is built once; a query only writes its time into the last column.
        self._inputs = np.empty((self.n_points, self.points.shape[1] + 1), dtype=np.float32)
        self._inputs[:, :-1] = self.points

    def frame(self, t: float) -> np.ndarray:
        self._inputs[:, -1] = t
        return self._full.run(self._inputs).reshape(-1)


class SeparableEvaluator(Evaluator):
    """u(x_i, t) = sum_k A[i, k] B(t)[k] + bias, with A computed once on the lattice."""

    kind = "separable"

    def __init__(
        self, space: GraphRunner, time_graph: GraphRunner, bias: float, points: np.ndarray
    ) -> None:
        super().__init__(points)
        self._time = time_graph
        self._bias = float(bias)
        # float64 A: the mat-vec then adds no rounding of its own to the graphs' float32.
        self._space_factor = space.run(self.points.astype(np.float32)).astype(np.float64)
        if self._space_factor.shape[0] != self.n_points:
            raise SceneError(f"space graph returned {self._space_factor.shape[0]} rows")
        self._time_input = np.zeros((1, 1), dtype=np.float32)
        terms = self._time.run(self._time_input).size  # checked once, not per query
        if terms != self.rank:
            raise SceneError(f"time graph returns {terms} terms, the space graph {self.rank}")

    @property
    def rank(self) -> int:
        """Number of separable terms r."""
        return int(self._space_factor.shape[1])

    def frame(self, t: float) -> np.ndarray:
        self._time_input[0, 0] = t
        time_factor = self._time.run(self._time_input).reshape(-1).astype(np.float64)
        result: np.ndarray = self._space_factor @ time_factor + self._bias
        return result

    def info(self) -> dict[str, Any]:
        return {"kind": self.kind, "rank": self.rank, "cache_bytes": self._space_factor.nbytes}


class FrameGrid:
    """Frames at model times k * dt, k = 0 .. last_step, computed once from a frame function.

    Args:
        compute: The frame function (model time -> (n,) displacement).
        dt: Time step.
        last_step: N: frames at steps 0 .. N.
        n_points: Length of a frame.
        dtype: Storage type (float32 for network outputs, float64 for the exact solution).
        label: Names the grid in progress logs.
    """

    def __init__(
        self,
        compute: Callable[[float], np.ndarray],
        dt: float,
        last_step: int,
        n_points: int,
        dtype: type[np.floating[Any]],
        label: str,
    ) -> None:
        self.dt = dt
        self.frames = np.empty((last_step + 1, n_points), dtype=dtype)
        started = last_report = time.monotonic()
        for step in range(last_step + 1):
            self.frames[step] = compute(step * dt)
            now = time.monotonic()
            if now - last_report >= 2.0:  # long precomputations show progress
                last_report = now
                logger.info("%s: %d/%d frames (%.0f s)", label, step + 1, last_step + 1,
                            now - started)  # fmt: skip
        self.frames.setflags(write=False)
        logger.info(
            "%s: %d frames x %d points, %d bytes, %.2f s",
            label, last_step + 1, n_points, self.frames.nbytes, time.monotonic() - started,
        )  # fmt: skip

    @staticmethod
    def bytes_needed(last_step: int, n_points: int, dtype: type[np.floating[Any]]) -> int:
        """Memory a grid of these dimensions takes."""
        return (last_step + 1) * n_points * np.dtype(dtype).itemsize

    @property
    def last_step(self) -> int:
        """N."""
        return int(self.frames.shape[0] - 1)

    def step_of(self, t: float) -> int | None:
        """The step whose time is ``t`` (to rounding), or None when ``t`` is off the grid."""
        position = t / self.dt
        step = round(position)
        on_grid = abs(position - step) <= 1e-9 * max(1.0, abs(position))
        return step if on_grid and 0 <= step <= self.last_step else None

    def interpolate(self, t: float) -> np.ndarray:
        """Linear interpolation between the two frames around ``t`` (clamped to the grid)."""
        position = min(max(t / self.dt, 0.0), float(self.last_step))
        low = min(int(position), self.last_step)
        high = min(low + 1, self.last_step)
        weight = position - low
        mixed: np.ndarray = (1.0 - weight) * self.frames[low] + weight * self.frames[high]
        return mixed


class TableEvaluator(Evaluator):
    """Every frame of the scene's time grid, computed at load from another evaluator.

    Args:
        source: The evaluator that computes the frames (once each).
        dt: Time step.
        last_step: N: frames at steps 0 .. N.
        max_bytes: Refuse (SceneError) when the table would need more memory than this.
    """

    kind = "table"

    def __init__(self, source: Evaluator, dt: float, last_step: int, max_bytes: int) -> None:
        super().__init__(source.points)
        self.source_kind = source.kind
        self.source_bytes = source.working_bytes  # the source stays: it computes the frames
        # Exact frames keep their float64 digits; network outputs are float32 to begin with.
        dtype = np.float64 if source.kind == "exact" else np.float32
        needed = FrameGrid.bytes_needed(last_step, self.n_points, dtype)
        if needed + self.source_bytes > max_bytes:
            working = f" (and {self.source_bytes} for its source)" if self.source_bytes else ""
            raise SceneError(
                f"table_max_bytes: a table of {last_step + 1} frames x {self.n_points} points "
                f"needs {needed} bytes{working}, more than the limit {max_bytes}"
            )
        self._grid = FrameGrid(source.frame, dt, last_step, self.n_points, dtype, "table")

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the table."""
        return int(self._grid.frames.nbytes)

    def frame(self, t: float) -> np.ndarray:
        step = self._grid.step_of(t)
        return self._grid.frames[step] if step is not None else self._grid.interpolate(t)

    def info(self) -> dict[str, Any]:
        info = {
            "kind": self.kind,
            "source": self.source_kind,
            "frames": self._grid.last_step + 1,
            "memory_bytes": self.memory_bytes,
        }
        if self.source_bytes:
            info["source_memory_bytes"] = self.source_bytes
        return info


class ExactEvaluator(Evaluator):
    """The exact solution (modal series or closed form) of the problem on the lattice.

    Memory is counted against ``max_bytes`` (a scene's ``table_max_bytes``): first the working
    memory, the series' tables and the spatial form on the lattice (a cached basis, a sine
    transform on grids, or the basis recomputed in blocks, whichever fits; never less than
    ``EXACT_WORKING_FLOOR_BYTES`` is allowed), then the frames of the time grid, computed
    once at load in float64 when they fit in what is left (about 1 ms per membrane frame
    otherwise); other times are computed on demand.

    Args:
        problem: The problem.
        points: (n, d) lattice coordinates.
        dt: Time step of the grid to precompute (None: compute every frame on demand).
        last_step: Last step of that grid.
        max_bytes: The memory budget.
        rtol: Truncation tolerance of a series (None: ``membrane_models.exact``'s default);
            fewer modes are faster and less accurate. Closed forms ignore it.

    Raises:
        SceneError: The working memory alone exceeds the budget (the message gives both).
        ValueError: rtol is not a positive number.
    """

    kind = "exact"

    def __init__(
        self,
        problem: Problem,
        points: np.ndarray,
        dt: float | None = None,
        last_step: int | None = None,
        max_bytes: int = DEFAULT_TABLE_MAX_BYTES,
        rtol: float | None = None,
    ) -> None:
        super().__init__(points)
        self.problem = problem
        self.max_bytes = int(max_bytes)
        self.rtol = rtol
        allowed = max(self.max_bytes, EXACT_WORKING_FLOOR_BYTES)
        self._solution, self._at_time = self._build(problem, allowed)
        self._grid: FrameGrid | None = None
        if dt is not None and last_step is not None:
            self._grid = self._precompute(dt, last_step)

    def _build(self, problem: Problem, allowed: int) -> tuple[ExactSolution, PointFrames]:
        from membrane_models.exact import DEFAULT_RTOL, exact_solution  # scipy: when used

        rtol = DEFAULT_RTOL if self.rtol is None else self.rtol
        try:
            solution = exact_solution(problem, rtol, max_bytes=allowed)
            frames = solution.on_points(self.points, max_bytes=allowed - solution.memory_bytes)
        except MemoryBudgetExceeded as exc:
            limit = (
                f"the limit {allowed}"
                if allowed == self.max_bytes
                else f"the {allowed} any exact evaluator may use (table_max_bytes {self.max_bytes})"
            )
            raise SceneError(
                f"table_max_bytes: the exact evaluator of {problem.name} on {self.n_points} "
                f"points: {exc.what} needs {exc.needed} bytes, more than {limit}"
            ) from None
        return solution, frames

    def _precompute(self, dt: float, last_step: int) -> FrameGrid | None:
        """The grid's frames, when they fit in what the working memory leaves of the budget."""
        needed = FrameGrid.bytes_needed(last_step, self.n_points, np.float64)
        if needed > self.max_bytes - self.working_bytes:
            logger.info("exact frames of %s computed per query (%d bytes, %d left of %d)",
                        self.problem.name, needed, max(0, self.max_bytes - self.working_bytes),
                        self.max_bytes)  # fmt: skip
            return None
        return FrameGrid(self._compute, dt, last_step, self.n_points, np.float64, "exact frames")

    @property
    def working_bytes(self) -> int:
        """The series' tables plus the frame function's spatial form and scratch."""
        return int(self._solution.memory_bytes + self._at_time.nbytes)

    @property
    def memory_bytes(self) -> int:
        """Everything counted against the budget: working memory and precomputed frames."""
        frames = 0 if self._grid is None else int(self._grid.frames.nbytes)
        return self.working_bytes + frames

    def _compute(self, t: float) -> np.ndarray:
        return np.asarray(self._at_time(t), dtype=np.float64).reshape(-1)

    def frame(self, t: float) -> np.ndarray:
        step = self._grid.step_of(t) if self._grid is not None else None
        return self._grid.frames[step] if step is not None and self._grid else self._compute(t)

    def info(self) -> dict[str, Any]:
        info = {
            "kind": self.kind,
            "problem": self.problem.name,
            "modes": int(self._solution.n_modes),
            "truncation_error": float(self._solution.truncation_error),
            "precomputed_frames": 0 if self._grid is None else self._grid.last_step + 1,
            "spatial_method": self._at_time.method,
            "working_bytes": self.working_bytes,
            "memory_bytes": self.memory_bytes,
            "max_bytes": self.max_bytes,
        }
        if self.rtol is not None:
            info["rtol"] = self.rtol
        return info


def build_evaluator(
    scene: Scene,
    source: ModelSource,
    *,
    threads: int = 1,
    optimization: str = "all",
    rtol: float | None = None,
    on_demand: bool = False,
) -> Evaluator:
    """Build the evaluator a scene asks for, on the scene's lattice (loading only what it needs).

    The keywords default to what ``membrane serve`` does; ``membrane tradeoff`` measures the
    others.

    Args:
        scene: The validated scene.
        source: The scene's model, resolved once by the caller (``resolve_source(scene)``); a
            bare problem with evaluator ``table`` is a table of the exact solution.
        threads: onnxruntime intra-op threads per graph.
        optimization: onnxruntime graph optimisation level (``runtime.OPTIMIZATION_LEVELS``).
        rtol: Truncation tolerance of the exact series, wherever the exact solution is used
            (None: the default).
        on_demand: Exact evaluator only: compute every frame per query instead of
            precomputing the frames of the scene's time grid.

    Raises:
        SceneError: The model cannot serve this scene (missing part-graphs, time domain too
            short, lattice of the wrong dimension, table too large, ...).
        ManifestError: A graph file does not match its manifest's sha256.
        ValueError: An unknown optimisation level, or rtol not a positive number.
    """
    points = scene.lattice.coordinates(source.spatial_bounds)
    if scene.evaluator == "exact":
        dt, last_step = (None, None) if on_demand else (scene.dt, scene.last_step)
        return ExactEvaluator(
            source.problem, points, dt, last_step, max_bytes=scene.table_max_bytes, rtol=rtol
        )
    manifest = source.manifest
    inner: Evaluator
    if manifest is None:  # a bare problem: only a table of its exact solution (frames in it)
        if scene.evaluator != "table":
            raise SceneError(
                f"scene {scene.name}: evaluator: {scene.evaluator!r} needs a trained model; "
                f"{source.problem.name} alone is served by 'exact' or 'table'"
            )
        inner = ExactEvaluator(source.problem, points, max_bytes=scene.table_max_bytes, rtol=rtol)
    else:
        _check_time_domain(scene, source)
        kind = None if scene.evaluator == "table" else scene.evaluator
        inner = _network_evaluator(scene, manifest, points, kind, threads, optimization)
    if scene.evaluator == "table":
        return TableEvaluator(inner, scene.dt, scene.last_step, scene.table_max_bytes)
    return inner


def _network_evaluator(
    scene: Scene,
    manifest: Manifest,
    points: np.ndarray,
    kind: str | None,
    threads: int,
    optimization: str,
) -> Evaluator:
    """A trained model's network or separable evaluator (kind None: the fastest it allows)."""
    if kind is None:
        kind = "separable" if manifest.separable else "network"

    def graph(role: str) -> GraphRunner:
        return load_graph(manifest, role, threads, optimization)

    if kind == "separable":
        if not manifest.separable:
            raise SceneError(
                f"scene {scene.name}: evaluator: model {manifest.name!r} has no space/time "
                "part-graphs; use 'network' or 'table'"
            )
        return SeparableEvaluator(graph("space"), graph("time"), manifest.bias, points)
    return NetworkEvaluator(graph("full"), points)


def _check_time_domain(scene: Scene, source: ModelSource) -> None:
    low, high = source.time_bounds
    if low > _TIME_SLACK or scene.duration > high + _TIME_SLACK:
        raise SceneError(
            f"scene {scene.name}: duration: {scene.duration} s reaches past the model's time "
            f"domain [{low}, {high}]; a network is not valid outside it"
        )
