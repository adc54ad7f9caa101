"""The speed/accuracy trade-off: every way of answering a query, measured end to end.

A *case* is one scene served one way: a model (a shipped zoo model, or the bare problem for the
exact reference), an evaluator, a lattice, and the real knobs behind them (onnxruntime intra-op
threads and graph optimisation level; the exact series' truncation tolerance). For each case a
real server runs in a separate process, a real ``Client`` sweeps the scene's time grid a few
times (the first sweep warms up), and the tool records

- query latency, p50 and p99, as the client sees it (round trip through ZeroMQ and msgpack);
- the relative L2 error of the served frames against the exact solution on that lattice and
  that time grid, ||u - u_exact|| / ||u_exact|| over all points and steps (float32 rounding of
  the wire included, so even the exact evaluator shows about 1e-8).

Cases that cannot be served (say a model whose time domain is shorter than the scene) are kept
with the reason, not dropped silently.

The accuracy half of the cases can run on an executor (``--executor ray``: each case's frames
served by a server of its own in a Ray task, ``case_accuracy``); the timings stay serial, one
case at a time in one server process, or the cases would measure each other. A case's frames do
not depend on where it was served, so its error is the same either way.
"""

from __future__ import annotations

import contextlib
import logging
import math
import multiprocessing
import multiprocessing.connection
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from membrane_client.client import Client
from membrane_errors import MembraneError
from membrane_models.artifacts.manifest import Manifest
from membrane_models.artifacts.zoo_index import list_models, resolve_model
from membrane_models.exact import exact_solution
from membrane_models.executors import Executor, Job
from membrane_models.problems import make_problem
from membrane_server.evaluators import build_evaluator
from membrane_server.runtime import OPTIMIZATION_LEVELS
from membrane_server.scene import Scene, SceneError, load_scene, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.source import ModelSource, resolve_source

__all__ = [
    "LATTICES",
    "OPTIMIZATION_LEVELS",
    "SCENE_PROBLEMS",
    "Accuracy",
    "Case",
    "CaseServer",
    "Measurement",
    "TradeoffError",
    "build_case",
    "case_accuracy",
    "measure_cases",
    "pareto_front",
    "plan_cases",
]

logger = logging.getLogger(__name__)

# The built-in scene each problem is measured on (its dt, duration and placement).
SCENE_PROBLEMS: dict[str, str] = {
    "rope": "string-forced",
    "rope-plucked": "string-plucked",
    "membrane": "membrane-forced",
}
# Lattice sizes per scene: a few spheres, the study's size, and a dense one.
LATTICES: dict[str, tuple[tuple[int, ...], ...]] = {
    "rope": ((20,), (100,), (1000,)),
    "rope-plucked": ((20,), (100,), (1000,)),
    "membrane": ((5, 5), (20, 20), (100, 100)),
}
# Knob variants, measured on the study's lattice size (the middle one) only.
_THREAD_VARIANTS = (2,)
_OPTIMIZATION_VARIANTS = ("basic", "disabled")
_RTOL_VARIANTS = (1e-3, 1e-6)
_HOST_TIMEOUT_S = 600.0


class TradeoffError(MembraneError):
    """The measuring machinery itself failed (not a case that cannot be served)."""


@dataclass(frozen=True)
class Case:
    """One way of serving one scene.

    Attributes:
        scene: The built-in scene it derives from (time grid, placement): a SCENE_PROBLEMS key.
        model: A zoo model's name (or a manifest path); None for the exact reference of the
            scene's problem.
        evaluator: ``network``, ``separable``, ``table`` or ``exact``.
        lattice: (nx,) or (nx, ny).
        threads: onnxruntime intra-op threads per graph.
        optimization: onnxruntime graph optimisation level (one of OPTIMIZATION_LEVELS).
        rtol: Truncation tolerance of the exact series; None is the server's default.
        on_demand: Exact only: compute every frame per query (as for times off the grid)
            instead of serving the frames the server precomputes on the time grid.
    """

    scene: str
    model: str | None
    evaluator: str
    lattice: tuple[int, ...]
    threads: int = 1
    optimization: str = "all"
    rtol: float | None = None
    on_demand: bool = False

    @property
    def knobs(self) -> str:
        """The non-default knobs, e.g. ``threads=2``; ``-`` when all are defaults."""
        parts = []
        if self.threads != 1:
            parts.append(f"threads={self.threads}")
        if self.optimization != "all":
            parts.append(f"opt={self.optimization}")
        if self.on_demand:
            parts.append("per query")
        if self.rtol is not None:
            parts.append(f"rtol={self.rtol:g}")
        return ", ".join(parts) or "-"

    @property
    def lattice_label(self) -> str:
        """``100`` or ``20x20``."""
        return "x".join(str(n) for n in self.lattice)

    @property
    def problem(self) -> str:
        """The problem of the scene."""
        return SCENE_PROBLEMS[self.scene]

    def scene_data(self) -> dict[str, Any]:
        """The scene to serve: the built-in scene with this model, evaluator and lattice."""
        base = load_scene(self.scene)
        data = base.model_dump(exclude={"source"})
        lattice = {"nx": self.lattice[0]}
        if len(self.lattice) == 2:
            lattice["ny"] = self.lattice[1]
        data.update(model=self._model_reference(), evaluator=self.evaluator, lattice=lattice)
        return data

    @property
    def model_label(self) -> str:
        """The model's name, or ``exact reference``."""
        return "exact reference" if self.model is None else self.model

    def _model_reference(self) -> str:
        """What the scene's ``model`` says: the problem, or the model's manifest path.

        A zoo model is named by its manifest's path: a zoo name equal to a problem name would
        mean the problem to the exact evaluator.
        """
        if self.model is None:
            return self.problem
        if Path(self.model).suffix in (".json", ".onnx"):
            return self.model
        manifest = resolve_model(self.model)
        return str(manifest.path) if manifest.path is not None else self.model


@dataclass
class Measurement:
    """What one case measured, or why it could not be measured.

    Latencies are in microseconds; errors are relative (L2) and absolute (max) over the
    scene's whole time grid and lattice.
    """

    case: Case
    p50_us: float = math.nan
    p99_us: float = math.nan
    mean_us: float = math.nan
    samples: int = 0
    relative_l2: float = math.nan
    max_abs_error: float = math.nan
    build_s: float = math.nan
    evaluator_info: dict[str, Any] = field(default_factory=dict)
    failure: str | None = None

    @property
    def ok(self) -> bool:
        """True when the case was measured."""
        return self.failure is None


# ---------------------------------------------------------------------------------------------
# Planning
# ---------------------------------------------------------------------------------------------


def plan_cases(scenes: Sequence[str] = tuple(SCENE_PROBLEMS), quick: bool = False) -> list[Case]:
    """Every case to measure for these scenes, given what the zoo ships now.

    Args:
        scenes: Scene names (keys of SCENE_PROBLEMS).
        quick: Smallest lattice only, no knob variants.

    Raises:
        SceneError: An unknown scene name.
    """
    cases: list[Case] = []
    for scene in scenes:
        if scene not in SCENE_PROBLEMS:
            known = ", ".join(SCENE_PROBLEMS)
            raise SceneError(f"tradeoff: unknown scene {scene!r}; known: {known}")
        problem = SCENE_PROBLEMS[scene]
        models = _shipped_models(problem)
        lattices = LATTICES[scene][:1] if quick else LATTICES[scene]
        for lattice in lattices:
            cases += [
                Case(scene, None, "exact", lattice),
                Case(scene, None, "table", lattice),
            ]
            for name, manifest in models:
                cases += [Case(scene, name, kind, lattice) for kind in _model_evaluators(manifest)]
        if not quick:
            cases += _knob_variants(scene, problem, models, LATTICES[scene][1])
    return cases


def _shipped_models(problem: str) -> list[tuple[str, Manifest]]:
    found = []
    for name in list_models():
        try:
            manifest = resolve_model(name)
        except ValueError as exc:  # a broken manifest is reported, not fatal to the sweep
            logger.warning("zoo model %s skipped: %s", name, exc)
            continue
        # A registry variant (string-plucked-smooth) belongs to its problem's scene.
        if make_problem(manifest.problem).name == problem:
            found.append((name, manifest))
    return found


def _model_evaluators(manifest: Manifest) -> list[str]:
    return ["network", *(["separable"] if manifest.separable else []), "table"]


def _knob_variants(
    scene: str, problem: str, models: list[tuple[str, Manifest]], lattice: tuple[int, ...]
) -> list[Case]:
    cases = []
    for name, manifest in models:
        for kind in _model_evaluators(manifest)[:-1]:  # the per-query graph runners
            base = Case(scene, name, kind, lattice)
            cases += [replace(base, threads=n) for n in _THREAD_VARIANTS]
            cases += [replace(base, optimization=level) for level in _OPTIMIZATION_VARIANTS]
    # The exact solution computed per query; for a series its truncation tolerance is a knob.
    cases.append(Case(scene, None, "exact", lattice, on_demand=True))
    if exact_solution(make_problem(problem)).n_modes > 0:
        cases += [
            Case(scene, None, "exact", lattice, rtol=r, on_demand=True) for r in _RTOL_VARIANTS
        ]
    return cases


# ---------------------------------------------------------------------------------------------
# Building a case's evaluator (in the server process)
# ---------------------------------------------------------------------------------------------


def build_case(case: Case) -> ServedScene:
    """The served scene of a case, built by the server's own ``build_evaluator`` with the
    case's knobs (``membrane serve`` builds the cases without knobs the same way).

    Raises:
        SceneError, ManifestError: The case cannot be served (the message says why).
        ValueError: A knob out of range (an unknown optimisation level, rtol <= 0).
    """
    scene = scene_from_dict(case.scene_data())
    source = _source(case, scene)
    try:
        evaluator = build_evaluator(
            scene,
            source,
            threads=case.threads,
            optimization=case.optimization,
            rtol=case.rtol,
            on_demand=case.on_demand,
        )
    except SceneError as exc:  # as ServedScene.load names the scene
        raise scene.error(exc) from None
    return ServedScene(scene, evaluator, source)


def _source(case: Case, scene: Scene) -> ModelSource:
    """The case's model, resolved as the server resolves a scene's.

    The exact reference is the bare problem, whatever the evaluator: a scene file can only
    name it with evaluator ``exact`` (with ``table`` a problem's name means its zoo model).
    """
    if case.model is None:
        return resolve_source(scene.model_copy(update={"evaluator": "exact"}))
    return resolve_source(scene)


def _host_main(connection: multiprocessing.connection.Connection) -> None:
    """The server process: build and serve one case at a time, as the parent asks."""
    from membrane_server.server import Server

    while True:
        case = connection.recv()
        if case is None:
            return
        try:
            started = time.perf_counter()
            served = build_case(case)
            build_s = time.perf_counter() - started
            server = Server([served], bind="tcp://127.0.0.1:*", threads=case.threads)
            address = server.start()
        except (ValueError, OSError) as exc:  # SceneError, ManifestError, InvalidProblem, bind
            connection.send(("failed", " ".join(str(exc).split())))
            continue
        connection.send(("ready", address, build_s))
        try:
            connection.recv()  # the parent says when it is done measuring
        finally:
            server.stop()
        connection.send(("stopped",))


class CaseServer:
    """A server process that serves one case at a time (also used by benchmarks/).

    Use as a context manager; ``serve(case)`` starts serving a case, ``done()`` stops it.
    """

    def __init__(self) -> None:
        context = multiprocessing.get_context("spawn")
        self._connection, child = context.Pipe()
        self._process = context.Process(
            target=_host_main, args=(child,), name="membrane-tradeoff-server", daemon=True
        )
        self._process.start()

    def serve(self, case: Case) -> tuple[str, float]:
        """Start serving ``case``; returns (address, build seconds). Raises SceneError."""
        self._connection.send(case)
        reply = self._receive()
        if reply[0] == "failed":
            raise SceneError(reply[1])
        return reply[1], reply[2]

    def done(self) -> None:
        """Stop serving the current case."""
        self._connection.send("stop")
        self._receive()

    def close(self) -> None:
        """End the server process."""
        with contextlib.suppress(OSError):  # the process may be gone already
            self._connection.send(None)
        self._process.join(timeout=10.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(timeout=5.0)

    def __enter__(self) -> CaseServer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _receive(self) -> tuple[Any, ...]:
        give_up = time.monotonic() + _HOST_TIMEOUT_S
        while not self._connection.poll(0.5):
            if not self._process.is_alive():
                raise TradeoffError("the server process died (see its log above)")
            if time.monotonic() > give_up:
                raise TradeoffError(f"the server process did not answer in {_HOST_TIMEOUT_S} s")
        reply: tuple[Any, ...] = self._connection.recv()
        return reply


# ---------------------------------------------------------------------------------------------
# Measuring
# ---------------------------------------------------------------------------------------------

Progress = Callable[[int, int, Case, Measurement], None]
"""Called after each case with (number done, total, case, its measurement)."""


def measure_cases(
    cases: Sequence[Case],
    rounds: int = 6,
    progress: Progress | None = None,
    executor: Executor | None = None,
) -> list[Measurement]:
    """Serve and measure every case, one at a time, in one server process.

    Args:
        cases: From ``plan_cases``.
        rounds: Sweeps over the time grid per case; the first is a warm-up (not timed).
        progress: Called after each case.
        executor: Where the cases' accuracy is measured first, each case served by a server of
            its own (``case_accuracy``); None: from the timing server's warm-up sweep. The
            timings are serial either way.
    """
    if rounds < 2:
        raise ValueError(f"rounds must be >= 2 (the first one warms up), got {rounds}")
    accuracies: list[Accuracy | None] = [None] * len(cases)
    if executor is not None:
        jobs = [Job(_case_name(case), case_accuracy, (case,)) for case in cases]
        accuracies = [*executor.run(jobs)]
    host = CaseServer()
    results = []
    try:
        for number, (case, accuracy) in enumerate(zip(cases, accuracies, strict=True), start=1):
            measurement = _measure_one(host, case, rounds, accuracy)
            results.append(measurement)
            if progress is not None:
                progress(number, len(cases), case, measurement)
    finally:
        host.close()
    return results


@dataclass(frozen=True)
class Accuracy:
    """A case's served frames against the exact solution, or why the case could not be served."""

    relative_l2: float = math.nan
    max_abs_error: float = math.nan
    failure: str | None = None


def case_accuracy(case: Case) -> Accuracy:
    """Serve ``case`` from a server in this process, sweep its time grid once with a real
    client, and compare the frames with the exact solution (a job for an executor)."""
    from membrane_server.server import Server

    try:
        served = build_case(case)
        server = Server([served], bind="tcp://127.0.0.1:*", threads=case.threads)
    except (ValueError, OSError) as exc:  # as the case server says it (``_host_main``)
        return Accuracy(failure=" ".join(str(exc).split()))
    try:
        address = server.start()
        with Client(address, timeout=60.0) as client:
            info = client.describe()
            times = info.start_offset + info.dt * np.arange(info.steps)
            frames = _sweep(client, times, rounds=1)[1]  # the first sweep alone: no timing
            points = np.asarray(info.points)
        return Accuracy(*_errors(case, points, times - info.start_offset, frames))
    except (MembraneError, OSError) as exc:  # a bind, a timeout, a refused query: this case's
        return Accuracy(failure=" ".join(str(exc).split()))
    finally:
        server.stop()


def _case_name(case: Case) -> str:
    return f"{case.scene} {case.lattice_label} {case.model_label} {case.evaluator} ({case.knobs})"


def _measure_one(
    host: CaseServer, case: Case, rounds: int, accuracy: Accuracy | None
) -> Measurement:
    if accuracy is not None and accuracy.failure is not None:
        return Measurement(case, failure=accuracy.failure)
    try:
        address, build_s = host.serve(case)
    except SceneError as exc:
        return Measurement(case, failure=str(exc))
    try:
        with Client(address, timeout=60.0) as client:
            info = client.describe()
            times = info.start_offset + info.dt * np.arange(info.steps)
            latencies, frames = _sweep(client, times, rounds)
            points = np.asarray(info.points)
            evaluator_info = {"kind": info.evaluator, **info.evaluator_info}
    finally:
        host.done()
    if accuracy is None:
        accuracy = Accuracy(*_errors(case, points, times - info.start_offset, frames))
    return Measurement(
        case,
        p50_us=float(np.percentile(latencies, 50)),
        p99_us=float(np.percentile(latencies, 99)),
        mean_us=float(np.mean(latencies)),
        samples=int(latencies.size),
        relative_l2=accuracy.relative_l2,
        max_abs_error=accuracy.max_abs_error,
        build_s=build_s,
        evaluator_info=evaluator_info,
    )


def _sweep(client: Client, times: np.ndarray, rounds: int) -> tuple[np.ndarray, np.ndarray]:
    """Query every step ``rounds`` times in order; (latencies in us after round 1, frames)."""
    latencies = np.empty((rounds - 1) * times.size)
    frames = np.empty((times.size, client.describe().n_points))
    for sweep in range(rounds):
        for step, t in enumerate(times):
            started = time.perf_counter()
            frame = client.query(float(t))
            elapsed = time.perf_counter() - started
            if sweep > 0:
                latencies[(sweep - 1) * times.size + step] = elapsed * 1e6
            else:
                frames[step] = frame.z.reshape(-1)
    return latencies, frames


def _errors(
    case: Case, points: np.ndarray, model_times: np.ndarray, frames: np.ndarray
) -> tuple[float, float]:
    """Relative L2 and max-abs error of (steps, n) frames against the exact solution."""
    scene = scene_from_dict(case.scene_data())
    problem = _source(case, scene).problem
    exact = exact_solution(problem).at_points(points, model_times).T  # (steps, n)
    difference = frames - exact
    norm = float(np.linalg.norm(exact))
    relative = float(np.linalg.norm(difference)) / norm if norm > 0 else math.nan
    return relative, float(np.max(np.abs(difference)))


# ---------------------------------------------------------------------------------------------
# Reading the results
# ---------------------------------------------------------------------------------------------


def pareto_front(measurements: Sequence[Measurement]) -> list[Measurement]:
    """The measured cases no other case beats on both p50 latency and error, fastest first.

    p50, not p99: on a shared machine a p99 over a few hundred queries is set by the other
    processes' time slices more than by the case itself.
    """
    measured = sorted((m for m in measurements if m.ok), key=lambda m: (m.p50_us, m.relative_l2))
    front: list[Measurement] = []
    best_error = math.inf
    for m in measured:
        if m.relative_l2 < best_error:
            front.append(m)
            best_error = m.relative_l2
    return front
