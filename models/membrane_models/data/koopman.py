"""Datasets of the Kirchhoff-Carrier string for data-driven networks (the Koopman model).

Each trajectory starts from a seeded shape of one family (``string_shapes``), at rest or with a
velocity, scaled so that its nonlinearity eps = k S* / c^2 (``nonlinear_string``) is a drawn
target: log-uniform between the spec's bounds, from linear (1e-3: a 4e-4 frequency shift) to
strongly nonlinear (1: the tension doubles at the largest stretch, frequencies rise by up to
32%). The modal solver gives (u, u_t) on ``points`` interior points x_i = i / (points + 1)
every ``dt``.

The split is by shape: every trajectory belongs to one of train, validation and test, each
written to its own .npz, and the test file is never to be read in training or model selection.
Trajectory i of a family in a split is drawn from its own seed (spec seed, family, split, i), so
a dataset's trajectories do not depend on how many others were asked for, and no two splits
share a shape.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_errors import UserError
from membrane_models.exact.kirchhoff_carrier import (
    DEFAULT_RTOL,
    KirchhoffString,
    solve_kirchhoff,
)
from membrane_models.problems.string_shapes import FAMILIES, ShapeParameters, draw_shape

__all__ = [
    "FORMAT",
    "SPLITS",
    "DatasetError",
    "DatasetSpec",
    "InitialState",
    "generate_split",
    "initial_state",
    "trajectory",
    "write_datasets",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int, str], None]  # (trajectories done, total, what was just done)

FORMAT = 1
SPLITS = ("train", "validation", "test")


class DatasetError(UserError):
    """A dataset specification that cannot be generated."""


@dataclass(frozen=True)
class DatasetSpec:
    """Everything that determines a dataset (with the seed, its bytes).

    Attributes:
        seed: Seeds every shape, amplitude and velocity.
        counts: Trajectories per family in train, validation and test.
        families: Shape families (``string_shapes.FAMILIES``).
        steps: Time steps per trajectory (snapshots: steps + 1, from t = 0).
        dt: Time between snapshots.
        points: Interior points of a snapshot.
        modes: Sine modes of the initial shapes (the solver's N).
        c: Wave speed.
        k: Stretch coefficient: with c = 1 and k = 100, mode 1 reaches eps = 1 at amplitude
            0.045 (4.5% of the length).
        nonlinearity: Bounds of the log-uniform eps = k S* / c^2.
        velocity_fraction: Share of trajectories that start with a velocity (a second shape of
            the family, with a uniform share of the energy).
        shapes: The families' parameters (smoothing widths, noise band, sine modes).
        rtol: DOP853's tolerance (``nonlinear_string.solve_kirchhoff``).
    """

    seed: int = 0
    counts: tuple[int, int, int] = (12, 3, 3)
    families: tuple[str, ...] = FAMILIES
    steps: int = 200
    dt: float = 0.01
    points: int = 128
    modes: int = 128
    c: float = 1.0
    k: float = 100.0
    nonlinearity: tuple[float, float] = (1e-3, 1.0)
    velocity_fraction: float = 0.5
    shapes: ShapeParameters = field(default_factory=ShapeParameters)
    rtol: float = DEFAULT_RTOL

    def __post_init__(self) -> None:
        unknown = sorted(set(self.families) - set(FAMILIES))
        if unknown or not self.families:
            raise DatasetError(f"families must be among {', '.join(FAMILIES)}; got {unknown}")
        if len(self.counts) != len(SPLITS) or min(self.counts) < 0 or sum(self.counts) == 0:
            raise DatasetError(f"counts must be {len(SPLITS)} numbers >= 0, not all 0")
        for name in ("steps", "points", "modes"):
            if getattr(self, name) < 1:
                raise DatasetError(f"{name} must be >= 1, got {getattr(self, name)}")
        low, high = self.nonlinearity
        if not (0.0 < low <= high and math.isfinite(high)):
            raise DatasetError(f"nonlinearity bounds must satisfy 0 < low <= high, got {low, high}")
        if not 0.0 <= self.velocity_fraction <= 1.0:
            fraction = self.velocity_fraction
            raise DatasetError(f"velocity_fraction must lie in [0, 1], got {fraction}")
        if not (self.dt > 0.0 and self.k > 0.0 and self.c > 0.0):
            raise DatasetError("dt, c and k must be > 0 (eps = k S* / c^2 needs k > 0)")
        if self.shapes.max_sine_mode > self.modes:
            raise DatasetError(f"max_sine_mode {self.shapes.max_sine_mode} > modes {self.modes}")

    @property
    def string(self) -> KirchhoffString:
        return KirchhoffString(self.c, self.k)

    def count(self, split: str) -> int:
        """Trajectories per family in ``split``."""
        return self.counts[SPLITS.index(split)]

    def x(self) -> FloatArray:
        """The snapshots' interior points i / (points + 1), i = 1..points."""
        return np.arange(1, self.points + 1, dtype=np.float64) / (self.points + 1)

    def t(self) -> FloatArray:
        """The snapshots' times j dt, j = 0..steps."""
        return np.arange(self.steps + 1, dtype=np.float64) * self.dt

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON), as the files record it."""
        return {
            "seed": self.seed,
            "counts": dict(zip(SPLITS, self.counts, strict=True)),
            "families": list(self.families),
            "steps": self.steps,
            "dt": self.dt,
            "points": self.points,
            "modes": self.modes,
            "c": self.c,
            "k": self.k,
            "nonlinearity": list(self.nonlinearity),
            "velocity_fraction": self.velocity_fraction,
            "shapes": self.shapes.to_dict(),
            "rtol": self.rtol,
        }


@dataclass(frozen=True)
class InitialState:
    """One trajectory's start: modal data, its family and what was drawn for it."""

    family: str
    drawn: dict[str, Any]
    q0: FloatArray
    p0: FloatArray
    nonlinearity: float
    has_velocity: bool


def initial_state(spec: DatasetSpec, family: str, split: str, index: int) -> InitialState:
    """Trajectory ``index`` of ``family`` in ``split``, from its own seed."""
    key = [spec.seed, FAMILIES.index(family), SPLITS.index(split), index]
    rng = np.random.default_rng(key)
    shape, drawn = draw_shape(family, rng, spec.modes, spec.shapes)
    sign = float(rng.choice((-1.0, 1.0)))
    low, high = spec.nonlinearity
    eps = float(math.exp(rng.uniform(math.log(low), math.log(high))))
    has_velocity = bool(rng.random() < spec.velocity_fraction)
    velocity, share = np.zeros(spec.modes), 0.0
    if has_velocity:
        velocity, drawn_velocity = draw_shape(family, rng, spec.modes, spec.shapes)
        share = float(rng.uniform(0.0, 1.0))
        drawn = {**drawn, "velocity": drawn_velocity, "kinetic_share": share}
    q0, p0 = _scaled(spec.string, sign * shape, velocity, share, eps)
    return InitialState(family, {**drawn, "sign": sign}, q0, p0, eps, has_velocity)


def _scaled(
    string: KirchhoffString, shape: FloatArray, velocity: FloatArray, share: float, eps: float
) -> tuple[FloatArray, FloatArray]:
    """(a q, a p) with ``share`` of the linear energy kinetic and nonlinearity ``eps``.

    With q and p normalised to linear potential and kinetic energy 1 - share and share, the
    energy of (a q, a p) is a^2 + a^4 k S(q)^2 / 4; eps needs E = c^4 (2 eps + eps^2) / (4 k),
    a quadratic in a^2 (solved without cancellation).
    """
    c2 = string.c**2
    q = shape * math.sqrt((1.0 - share) / (0.5 * c2 * float(string.stretch(shape))))
    p = np.zeros_like(velocity)
    if share > 0.0:
        p = velocity * math.sqrt(share / (0.25 * float(np.sum(velocity**2))))
    quartic = 0.25 * string.k * float(string.stretch(q)) ** 2
    target = c2 * c2 * (2.0 * eps + eps * eps) / (4.0 * string.k)
    a2 = 2.0 * target / (1.0 + math.sqrt(1.0 + 4.0 * quartic * target))
    return q * math.sqrt(a2), p * math.sqrt(a2)


def trajectory(spec: DatasetSpec, family: str, split: str, index: int) -> dict[str, Any]:
    """One trajectory's row of its split's file (see ``write_datasets``)."""
    state = initial_state(spec, family, split, index)
    solution = solve_kirchhoff(spec.string, state.q0, state.p0, spec.t(), spec.rtol)
    u, u_t = solution.at_points(spec.x())
    energy = solution.energy()
    return {
        "u": u,
        "u_t": u_t,
        "family": family,
        "shape": json.dumps(state.drawn, sort_keys=True),
        "nonlinearity": state.nonlinearity,
        "amplitude": float(np.max(np.abs(u[0]))),
        "energy": float(energy[0]),
        "energy_drift": float(np.max(np.abs(energy - energy[0])) / energy[0]),
        "has_velocity": state.has_velocity,
        "q0": state.q0,
        "p0": state.p0,
    }


def _row(task: tuple[DatasetSpec, str, str, int]) -> dict[str, Any]:
    return trajectory(*task)


def generate_split(
    spec: DatasetSpec,
    split: str,
    progress: Progress | None = None,
    done: int = 0,
    executor: Executor | None = None,
) -> dict[str, np.ndarray]:
    """Every trajectory of ``split`` as the arrays of its .npz file (see ``write_datasets``).

    With an ``executor`` (a process pool) the trajectories are computed in parallel; each has
    its own seed, so the arrays are the same either way.
    """
    tasks = [(spec, f, split, i) for f in spec.families for i in range(spec.count(split))]
    rows = executor.map(_row, tasks) if executor is not None else map(_row, tasks)
    total = sum(spec.counts) * len(spec.families)
    columns: dict[str, list[Any]] = {key: [] for key in _PER_TRAJECTORY}
    for task, row in zip(tasks, rows, strict=True):
        for key, value in row.items():
            columns[key].append(value)
        done += 1
        if progress is not None:
            progress(done, total, f"{split} {task[1]}")
    return _arrays(spec, split, columns)


_PER_TRAJECTORY = (
    "u",
    "u_t",
    "family",
    "shape",
    "nonlinearity",
    "amplitude",
    "energy",
    "energy_drift",
    "has_velocity",
    "q0",
    "p0",
)


def _arrays(spec: DatasetSpec, split: str, columns: dict[str, list[Any]]) -> dict[str, np.ndarray]:
    empty = {
        "u": (0, spec.steps + 1, spec.points),
        "u_t": (0, spec.steps + 1, spec.points),
        "q0": (0, spec.modes),
        "p0": (0, spec.modes),
    }
    arrays: dict[str, np.ndarray] = {}
    for key, values in columns.items():
        arrays[key] = np.asarray(values) if values else np.zeros(empty.get(key, (0,)))
    arrays["family"] = arrays["family"].astype(str)
    arrays["shape"] = arrays["shape"].astype(str)
    arrays["has_velocity"] = arrays["has_velocity"].astype(bool)
    parameters = {"format": FORMAT, "generator": __name__, **spec.to_dict()}
    return {
        **arrays,
        "x": spec.x(),
        "t": spec.t(),
        "split": np.array(split),
        "parameters": np.array(json.dumps(parameters, sort_keys=True)),
    }


def write_datasets(
    spec: DatasetSpec,
    out_dir: Path,
    progress: Progress | None = None,
    jobs: int = 1,
    executor: Executor | None = None,
) -> dict[str, Path]:
    """Write OUT/train.npz, OUT/validation.npz and OUT/test.npz; returns their paths.

    ``jobs`` > 1 computes trajectories in that many processes, or ``executor`` (Ray's,
    ``executors.RayExecutor.futures``) where it sends them: the same bytes as one.

    Each file holds ``u`` and ``u_t`` shaped (trajectories, steps + 1, points), ``x``, ``t``,
    per trajectory ``family``, ``shape`` (JSON of what was drawn), ``nonlinearity``,
    ``amplitude`` (max |u| at t = 0), ``energy``, ``energy_drift`` (largest relative change
    over the snapshots), ``has_velocity``, the modal data ``q0`` and ``p0``, and ``split`` and
    ``parameters`` (JSON of the spec, with the format number).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    with ExitStack() as stack:
        if executor is None and jobs > 1:
            executor = stack.enter_context(ProcessPoolExecutor(jobs))
        return _write_splits(spec, out_dir, progress, executor)


def _write_splits(
    spec: DatasetSpec, out_dir: Path, progress: Progress | None, executor: Executor | None
) -> dict[str, Path]:
    paths: dict[str, Path] = {}
    done = 0
    for split in SPLITS:
        # Any: numpy's stubs read ** into savez's own keyword arguments.
        arrays: dict[str, Any] = generate_split(spec, split, progress, done, executor)
        done += spec.count(split) * len(spec.families)
        path = out_dir / f"{split}.npz"
        tmp = out_dir / f".{split}.tmp.npz"
        with tmp.open("wb") as handle:
            np.savez(handle, **arrays)
        tmp.replace(path)  # never a half-written dataset under the final name
        paths[split] = path
    return paths
