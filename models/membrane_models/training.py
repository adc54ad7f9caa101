"""Physics-informed training: recipes, collocation, the residual loss, the loop, checkpoints.

The loss is the PDE residual alone for our recipes (boundary and initial conditions are exact by
construction, see ``transforms``), plus initial-condition terms for the published configuration,
which enforces them softly. No solution data enters the loss.

The residual is evaluated on a Cartesian collocation grid (per-axis stratified random points,
resampled every Adam step): for a separable model u = A @ B^T on the grid, so u_tt = A @ B''^T
and Laplacian(u) = Lap(A) @ B^T cost one small matrix product each. The L-BFGS phase uses one
fixed, finer grid (L-BFGS needs a fixed objective).

Checkpoints are ``torch.save`` of tensors and plain data only, loadable with ``weights_only``.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from membrane_errors import UserError
from membrane_models.networks import build_core
from membrane_models.problems import Problem, StringPlucked, make_problem, time_bump
from membrane_models.transforms import TIME_BUMP_PEAK, PhysicalModel, characteristic_amplitude

__all__ = [
    "CHECKPOINT_FORMAT",
    "RECIPES",
    "TrainConfig",
    "TrainResult",
    "build_model",
    "load_checkpoint",
    "model_from_checkpoint",
    "recipe",
    "train",
]

logger = logging.getLogger(__name__)

CHECKPOINT_FORMAT = 1
Monitor = Callable[[PhysicalModel], dict[str, float]]


@dataclass
class TrainConfig:
    """Everything that determines a training run (with the seed, the run is deterministic).

    Attributes:
        problem: Registry name of the problem.
        overrides: Problem parameter overrides, NAME -> value as typed.
        arch: Network config for ``networks.build_core`` (``seed`` is filled from ``seed``).
        iterations: Total optimiser iterations (Adam first, then L-BFGS).
        lbfgs_fraction: Share of the iterations done by L-BFGS at the end (0 for Adam only).
        lr: Adam's initial learning rate.
        lr_final: Adam's learning rate at its last step (exponential decay in between);
            None for the published inverse-time decay (0.9 every 2000 steps).
        space_points: Collocation points per space axis for Adam (grid) or in all (scattered).
        time_points: Collocation points on the time axis for Adam (grid mode).
        lbfgs_space_points: Fixed grid for L-BFGS, per space axis.
        lbfgs_time_points: Fixed grid for L-BFGS, time axis.
        lbfgs_resample_every: L-BFGS iterations between fresh grids (and a fresh curvature
            history), so that it cannot fit one grid at the expense of the points in between;
            0: one grid for the whole phase.
        modal_modes: Add the ``modal`` loss term with this many sine modes per space axis
            (0: off; grid sampling only). See ``modal_term``.
        modal_weight: The modal term's weight in the loss (the residual's is 1).
        modal_points: Project the residual for the modal term on its own uniform grid of this
            many points per axis, space and time (0: on the collocation grid).
        kink_modes: The kinked pluck's Dirac (its w'' at x0) enters the pointwise residual
            through this many sine modes (0: not at all; the modal term sees it either way).
        scattered: Sample scattered (x, t) points instead of a grid (the published sampling).
        initial_points: Points for the soft initial-condition terms (when not hard).
        hard_initial: Enforce u = u_t = 0 at t = 0 by the output transform.
        output_scaling: Scale outputs by the characteristic amplitude and the residual by the
            force's peak (False reproduces the published, unscaled training).
        seed: Seeds the weights, the Fourier frequencies and the collocation sampler.
        dtype: "float64" or "float32" for training (export is float32 either way).
        checkpoint_every: Iterations between checkpoints.
        monitor_every: Iterations between calls of the monitor (0: never).
        average_window: Average the weights over this many last iterations and end with the
            average (0: end with the last weights). Each L-BFGS grid pulls the weights its own
            way; the average of several grids' solutions is steadier than any one of them.
    """

    problem: str
    overrides: dict[str, str] = field(default_factory=dict)
    arch: dict[str, Any] = field(default_factory=dict)
    iterations: int = 10000
    lbfgs_fraction: float = 0.2
    lr: float = 1e-3
    lr_final: float | None = 1e-5
    space_points: int = 128
    time_points: int = 128
    lbfgs_space_points: int = 192
    lbfgs_time_points: int = 192
    lbfgs_resample_every: int = 250
    modal_modes: int = 0
    modal_weight: float = 1.0
    modal_points: int = 0
    kink_modes: int = 0
    scattered: bool = False
    initial_points: int = 360
    hard_initial: bool = True
    output_scaling: bool = True
    seed: int = 0
    dtype: str = "float64"
    checkpoint_every: int = 500
    average_window: int = 0
    monitor_every: int = 0

    @property
    def lbfgs_iterations(self) -> int:
        return round(self.iterations * self.lbfgs_fraction)

    @property
    def adam_iterations(self) -> int:
        return self.iterations - self.lbfgs_iterations


def _harmonic(features: int, decay: float = 0.0) -> dict[str, Any]:
    spec: dict[str, Any] = {"kind": "harmonic", "features": features, "include_input": True}
    if decay:
        spec["decay"] = decay
    return spec


# Both plucks share a network wide enough in frequency for the travelling corners, and a loss
# in which the modal term outweighs the pointwise residual: near a corner a smooth network can
# only round the kink off, so that residual stays large and would otherwise decide the fit.
# Sine mode n rings at c n pi, which is harmonic c t_end n of the time features (64 reach mode
# 32; the kinked pluck takes 128), and the skip paths put every harmonic one weight from the
# output: through tanh layers alone, modes above 16 were never learned (docs/MODELS.md).
_PLUCKED: dict[str, Any] = {
    "arch": {"name": "spinn", "rank": 64, "width": 64, "depth": 3,
             "space_features": _harmonic(32, decay=1.0),
             "time_features": _harmonic(64, decay=1.0), "skip": True},
    "iterations": 14000,
    "lbfgs_fraction": 0.85,
    "lbfgs_space_points": 256,
    "lbfgs_time_points": 256,
    "modal_weight": 1e6,
}

# The shipped recipes (chosen by measurement, docs/MODELS.md) and the published configuration.
RECIPES: dict[str, dict[str, Any]] = {
    "string-forced": {
        "arch": {"name": "spinn", "rank": 32, "width": 64, "depth": 3,
                 "space_features": _harmonic(16), "time_features": _harmonic(8)},
        "iterations": 12000,
        "lbfgs_fraction": 0.85,
        "lbfgs_space_points": 256,
        "lbfgs_time_points": 256,
        "modal_modes": 16,
        # The residual left is mostly high modes; the error is 99.9% modes 1-8 (free ringing
        # at their natural frequencies), which only the modal term sees: weigh it up.
        "modal_weight": 100.0,
    },
    # The kink's Dirac (w'' at x0) is seen through its first 64 sine modes, in the pointwise
    # residual and, analytically, in the modal term; that term projects on its own uniform grid,
    # so that one fixed L-BFGS grid serves: on the drawn grids the network cancelled its
    # low-mode residual in the grid's quadrature instead (docs/MODELS.md). Mode 64 rings at
    # time harmonic 128.
    "string-plucked": {**_PLUCKED,
                       "arch": {**_PLUCKED["arch"], "space_features": _harmonic(64, decay=1.0),
                                "time_features": _harmonic(128, decay=1.0)},
                       "modal_modes": 64, "kink_modes": 64, "modal_points": 256,
                       "iterations": 12000, "lbfgs_fraction": 0.825,
                       "lbfgs_resample_every": 0},
    # One fixed L-BFGS grid: redrawing it every 250 iterations restarted L-BFGS's curvature
    # history each time and left the fit wandering at 3e-3. The modal term on its own grid
    # reached the target in half the iterations it took on the collocation grid.
    "string-plucked-smooth": {**_PLUCKED, "modal_modes": 48, "modal_points": 256,
                              "iterations": 16000, "lbfgs_fraction": 0.86875,
                              "lbfgs_resample_every": 0},
    "membrane-forced": {
        "arch": {"name": "spinn", "rank": 48, "width": 64, "depth": 3,
                 "space_features": _harmonic(12), "time_features": _harmonic(12)},
        # L-BFGS on a fixed 48^2 x 64 grid drove the residual down and the error up while the
        # modal term was projected on that grid (docs/MODELS.md); on its own grid it holds.
        "iterations": 10000,
        "lbfgs_fraction": 0.3,
        "space_points": 48,
        "time_points": 64,
        "lbfgs_space_points": 48,
        "lbfgs_time_points": 64,
        "lbfgs_resample_every": 0,
        "modal_modes": 8,
        "modal_points": 64,
    },
}

# The published DeepXDE setup (seed-facts.md), for the comparison benchmark.
PUBLISHED: dict[str, dict[str, Any]] = {
    "string-forced": {"sigmas_x": [1.0], "sigmas_t": [1.0, 50.0]},
    "membrane-forced": {"sigmas_x": [1.0], "sigmas_t": [1.0, 10.0]},
}


def recipe(problem: str, family: str | None = None, **changes: Any) -> TrainConfig:
    """The training configuration for a problem: ours by default, or ``family="stmsffn"``.

    ``family="stmsffn"`` gives the published configuration (STMsFFN as published, Adam 1e-3 with
    inverse-time decay, 1440 scattered points, soft initial conditions, no output scaling).
    Keyword ``changes`` override any ``TrainConfig`` field.
    """
    if family in (None, "spinn"):
        if problem not in RECIPES:
            raise UserError(f"no recipe for {problem!r}; known: {', '.join(sorted(RECIPES))}")
        base: dict[str, Any] = {"problem": problem, **RECIPES[problem]}
        base["arch"] = dict(base["arch"])
    elif family == "stmsffn":
        sigmas = PUBLISHED.get(problem, {"sigmas_x": [1.0], "sigmas_t": [1.0, 10.0]})
        base = {
            "problem": problem,
            "arch": {"name": "stmsffn", "width": 100, "hidden": 3, "shared": True, **sigmas},
            "iterations": 20000,
            "lbfgs_fraction": 0.0,
            "lr": 1e-3,
            "lr_final": None,
            "scattered": True,
            "space_points": 1440,
            "initial_points": 360,
            "hard_initial": False,
            "output_scaling": False,
            "dtype": "float32",
        }
    else:
        raise UserError(f"unknown architecture {family!r}; known: spinn, stmsffn")
    base.update(changes)
    return TrainConfig(**base)


def build_model(config: TrainConfig) -> PhysicalModel:
    """A fresh, seeded model for a configuration."""
    problem = make_problem(config.problem, config.overrides)
    arch = {**config.arch, "spatial_dims": problem.spatial_dims, "seed": config.seed}
    core = build_core(arch)
    scale = characteristic_amplitude(problem) if config.output_scaling else 1.0
    model = PhysicalModel(core, problem, scale, hard_initial=config.hard_initial)
    return model.to(getattr(torch, config.dtype))


# ---------------------------------------------------------------- collocation and loss


def _stratified(n: int, high: float, generator: torch.Generator, dtype: torch.dtype) -> Tensor:
    """n points in [0, high], one uniform draw per equal cell (covers the ends every time)."""
    jitter = torch.rand(n, generator=generator, dtype=torch.float64)
    return ((torch.arange(n, dtype=torch.float64) + jitter) * (high / n)).to(dtype)


def _forcing_grid(problem: Problem, space: list[Tensor], t: Tensor) -> Tensor:
    """f on the grid (space points flattened, time), shape (n_space, n_t)."""
    if isinstance(problem, StringPlucked):
        n = math.prod(s.shape[0] for s in space)
        return torch.zeros(n, t.shape[0], dtype=t.dtype)
    coords = [s.detach().cpu().numpy() for s in space]
    mesh = np.meshgrid(*coords, indexing="ij")
    profile = problem.force_space(*mesh).reshape(-1)  # type: ignore[attr-defined]
    bump = time_bump(t.detach().cpu().numpy(), problem.a)  # type: ignore[attr-defined]
    return torch.from_numpy(np.outer(profile, bump)).to(t.dtype)


def _residual_scale(model: PhysicalModel, config: TrainConfig) -> float:
    """The residual's characteristic size, so that the loss starts near 1."""
    if not config.output_scaling:
        return 1.0
    problem = model.problem
    if isinstance(problem, StringPlucked):
        return problem.c**2 * model.scale * math.pi**2
    return TIME_BUMP_PEAK * abs(problem.h) or 1.0  # type: ignore[attr-defined]


@dataclass
class Collocation:
    """One set of collocation points: a grid (space axes, time) or scattered points."""

    space: list[Tensor]
    time: Tensor
    scattered: bool = False
    forcing: Tensor | None = None


def sample_collocation(
    problem: Problem, config: TrainConfig, generator: torch.Generator, fine: bool = False
) -> Collocation:
    """Draw collocation points (``fine``: the L-BFGS grid)."""
    dtype = getattr(torch, config.dtype)
    dims = problem.spatial_dims
    if config.scattered and not fine:
        n = config.space_points
        space = [_uniform(n, 1.0, generator, dtype) for _ in range(dims)]
        t = _uniform(n, problem.t_end, generator, dtype)[:, None]
        forcing = _forcing_points(problem, space, t)
        return Collocation(space, t, scattered=True, forcing=forcing)
    ns = config.lbfgs_space_points if fine else config.space_points
    nt = config.lbfgs_time_points if fine else config.time_points
    space = [_stratified(ns, 1.0, generator, dtype) for _ in range(dims)]
    t = _stratified(nt, problem.t_end, generator, dtype)[:, None]
    return Collocation(space, t, forcing=_forcing_grid(problem, space, t))


def _uniform(n: int, high: float, generator: torch.Generator, dtype: torch.dtype) -> Tensor:
    return (torch.rand(n, generator=generator, dtype=torch.float64) * high).to(dtype)


def _forcing_points(problem: Problem, space: list[Tensor], t: Tensor) -> Tensor:
    if isinstance(problem, StringPlucked):
        return torch.zeros(t.shape[0], dtype=t.dtype)
    coords = [s.numpy() for s in space]
    values = problem.forcing(*coords, t[:, 0].numpy())  # type: ignore[attr-defined]
    return torch.from_numpy(np.asarray(values)).to(t.dtype)


def loss_terms(
    model: PhysicalModel, points: Collocation, config: TrainConfig, generator: torch.Generator
) -> dict[str, Tensor]:
    """The loss terms: mean squared scaled residual (+ soft initial conditions)."""
    c2 = model.problem.c**2
    scale = _residual_scale(model, config)
    time_jet = model.time_jet(points.time)
    b, b_tt = time_jet.value, time_jet.d2[0]
    if points.scattered:
        space_jet = model.space_jet(torch.stack(points.space, 1))
        u_tt = torch.sum(space_jet.value * b_tt, 1)
        lap = torch.sum(space_jet.laplacian() * b, 1)
    else:
        space_jet = model.space_grid_jet(points.space)
        u_tt = space_jet.value @ b_tt.T
        lap = space_jet.laplacian() @ b.T
    assert points.forcing is not None
    residual = u_tt - c2 * lap - points.forcing
    kink = _kink_series(model, config.kink_modes, points) if config.kink_modes else None
    pointwise = residual if kink is None else residual + kink
    terms = {"residual": torch.mean((pointwise / scale) ** 2)}
    if config.modal_modes and not points.scattered:
        if config.modal_points:
            coeffs, wavenumber, times = _projected_residual(
                model, config.modal_modes, config.modal_points
            )
        else:
            coeffs, wavenumber = _sine_coefficients(residual, points.space, config.modal_modes)
            singular = _kink_coefficients(model.problem, config.modal_modes, residual.dtype)
            if singular is not None:
                coeffs = coeffs + singular[:, None]
            times = points.time
        terms["modal"] = config.modal_weight * modal_term(
            coeffs, wavenumber, times, math.sqrt(c2), model.scale
        )
    if not config.hard_initial:
        terms.update(_initial_terms(model, config, generator))
    return terms


def _sine_coefficients(grid: Tensor, space: list[Tensor], modes: int) -> tuple[Tensor, Tensor]:
    """Sine coefficients (M, n_t) of a (n_space, n_t) grid and each mode's wavenumber |n|.

    Quadrature: the collocation points (stratified, so each stands for one cell of its axis).
    """
    n = torch.arange(1, modes + 1, dtype=grid.dtype)
    projections = [2.0 / s.shape[0] * torch.sin(math.pi * n[:, None] * s[None, :]) for s in space]
    grid = grid.reshape(*[s.shape[0] for s in space], grid.shape[-1])
    if len(space) == 1:
        return projections[0] @ grid, n
    coeffs = torch.einsum("ki,lj,ijt->klt", projections[0], projections[1], grid)
    wavenumber = torch.sqrt(n[:, None] ** 2 + n[None, :] ** 2).reshape(-1)
    return coeffs.reshape(-1, grid.shape[-1]), wavenumber


def _projected_residual(
    model: PhysicalModel, modes: int, points: int
) -> tuple[Tensor, Tensor, Tensor]:
    """The residual's sine coefficients (M, points), wavenumbers and times, on a uniform grid.

    The projection needs only A's own sine coefficients a_n: since A and the sines vanish on
    the boundary, the Laplacian moves onto the sines by parts, so that r_n = a_n . B'' +
    c^2 (pi |n|)^2 a_n . B - f_n. On a uniform midpoint grid a_n is exact to rounding for a
    network's smooth factors, whatever the collocation draw: on the drawn grids the network
    learned to cancel its low-mode residual in that grid's quadrature, not in the integral.
    The kinked pluck's column gets its exact coefficients (the midpoint rule is only
    second-order at the kink).
    """
    problem, c2 = model.problem, model.problem.c**2
    dtype = next(model.parameters()).dtype
    axes, times = _midpoint_grid(problem, points, dtype)
    a, wavenumber = _sine_coefficients(model.space_grid(axes), axes, modes)
    kink = _kink_coefficients(problem, modes, dtype)
    if kink is not None:
        a = torch.cat([a[:, :-1], (kink / (c2 * (math.pi * wavenumber) ** 2))[:, None]], 1)
    jet = model.time_jet(times[:, None])
    coeffs = a @ jet.d2[0].T + (c2 * (math.pi * wavenumber) ** 2)[:, None] * (a @ jet.value.T)
    if not isinstance(problem, StringPlucked):
        coeffs = coeffs - _forcing_coefficients(problem, modes, points, dtype)
    return coeffs, wavenumber, times[:, None]


def _midpoint_grid(
    problem: Problem, points: int, dtype: torch.dtype
) -> tuple[list[Tensor], Tensor]:
    """The projection's uniform midpoint grid: ``points`` per space axis and in time."""
    unit = (torch.arange(points, dtype=dtype) + 0.5) / points
    times = (torch.arange(points, dtype=dtype) + 0.5) * (problem.t_end / points)
    return [unit] * problem.spatial_dims, times


@functools.lru_cache(maxsize=4)
def _forcing_coefficients(problem: Problem, modes: int, points: int, dtype: torch.dtype) -> Tensor:
    """f's sine coefficients on ``_projected_residual``'s grid (fixed, so computed once)."""
    axes, times = _midpoint_grid(problem, points, dtype)
    return _sine_coefficients(_forcing_grid(problem, axes, times), axes, modes)[0]


def _kink_coefficients(problem: Problem, modes: int, dtype: torch.dtype) -> Tensor | None:
    """Sine coefficients (modes,) of the residual's Dirac part for the kinked pluck, else None.

    The triangle's w'' is a Dirac of weight -(h/x0 + h/(1-x0)) at x0, which no collocation point
    sees: at points, the static triangle solves the equation, so without this part the residual
    is blind to the pluck. Its column enters u with B = 1, so the residual holds -c^2 w'' at
    every time, with sine coefficients -c^2 * 2 * weight * sin(n pi x0).
    """
    if not isinstance(problem, StringPlucked) or problem.smoothing > 0.0:
        return None
    weight = -(problem.height / problem.x0 + problem.height / (1.0 - problem.x0))
    n = torch.arange(1, modes + 1, dtype=dtype)
    return -problem.c**2 * 2.0 * weight * torch.sin(math.pi * n * problem.x0)


def _kink_series(model: PhysicalModel, modes: int, points: Collocation) -> Tensor | None:
    """The Dirac part's first ``modes`` sine modes at the grid's space points, shape (n, 1).

    Added to the pointwise residual, it makes that residual agree with the modal term: without
    it the pointwise residual is smallest for a string that never leaves the triangle, and it
    held every mode the modal term does not outweigh (above about 20) frozen there.
    """
    coeffs = _kink_coefficients(model.problem, modes, points.time.dtype)
    if coeffs is None or points.scattered:
        return None
    n = torch.arange(1, modes + 1, dtype=coeffs.dtype)
    x = points.space[0]
    return torch.sin(math.pi * x[:, None] * n[None, :]) @ coeffs[:, None]


def modal_term(
    coeffs: Tensor, wavenumber: Tensor, t: Tensor, c: float, amplitude: float
) -> Tensor:
    """The displacement error that the residual's low sine modes cause, relative to S.

    With u = u_exact + e, the error obeys the same wave equation driven by the residual:
    e_tt - c^2 Laplacian(e) = r, e = e_t = 0 at t = 0. Per sine mode n (angular frequency
    w_n = c pi |n|) that is Duhamel's integral e_n(t) = int_0^t sin(w_n (t - s)) / w_n r_n(s) ds.
    A low mode's residual is small for a large error (and a resonant one keeps growing), so the
    mean-square residual hardly sees the error that dominates the relative L2 norm; this term
    measures that error directly: mean (e_n(t_j) / S)^2 over the modes of ``coeffs`` (the
    residual's sine coefficients, (modes, n_t), see ``_sine_coefficients`` and
    ``_kink_coefficients``, or ``_projected_residual``) and the time points. It is the residual
    under a fixed linear operator: zero exactly where the residual is, and it uses nothing of
    the solution.
    """
    omega = c * math.pi * wavenumber  # (M,)
    error = _duhamel(coeffs, omega, t[:, 0])
    return torch.mean((error / amplitude) ** 2)


def _duhamel(coeffs: Tensor, omega: Tensor, times: Tensor) -> Tensor:
    """e_m(t_j) = cell * sum over s_i < t_j of sin(w_m (t_j - s_i)) / w_m * r_m(s_i).

    sin(w (t - s)) = sin(w t) cos(w s) - cos(w t) sin(w s) turns the sum into two running
    (exclusive) sums: O(modes x n_t) instead of a (modes, n_t, n_t) kernel, which made the
    term cost twice the residual itself at 48 modes. ``times`` must be sorted.
    """
    cell = (times[-1] - times[0]) / max(times.shape[0] - 1, 1)
    phase = omega[:, None] * times[None, :]  # (M, n_t)
    cos, sin = torch.cos(phase), torch.sin(phase)
    before_cos = torch.cumsum(cos * coeffs, 1) - cos * coeffs  # sum over i < j
    before_sin = torch.cumsum(sin * coeffs, 1) - sin * coeffs
    return (sin * before_cos - cos * before_sin) / omega[:, None] * cell


def _initial_terms(
    model: PhysicalModel, config: TrainConfig, generator: torch.Generator
) -> dict[str, Tensor]:
    """Soft u(x, 0) = w(x) and u_t(x, 0) = 0 (w = 0 for the forced problems), at t = 0."""
    dtype = getattr(torch, config.dtype)
    x = torch.stack(
        [_uniform(config.initial_points, 1.0, generator, dtype) for _ in range(model.spatial_dims)],
        1,
    )
    t0 = torch.zeros(1, 1, dtype=dtype)
    jet = model.time_jet(t0)
    a = model.space(x)
    u0 = a @ jet.value[0]
    ut0 = a @ jet.d1[0][0]
    target = torch.zeros_like(u0)
    if model.plucked:
        assert isinstance(model.problem, StringPlucked)
        from membrane_models.transforms import initial_shape_jet

        target = initial_shape_jet(model.problem, x[:, :1])[0][:, 0]
    norm = model.scale
    return {
        "initial": torch.mean(((u0 - target) / norm) ** 2),
        "velocity": torch.mean((ut0 * model.t_end / norm) ** 2),
    }


# ---------------------------------------------------------------- checkpoints


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a checkpoint (tensors and plain data only)."""
    if not path.is_file():
        raise UserError(f"no checkpoint at {path}")
    try:
        data: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a file that is not a checkpoint
        raise UserError(f"{path} is not a readable checkpoint: {exc}") from None
    if data.get("format") != CHECKPOINT_FORMAT:
        raise UserError(f"{path}: checkpoint format {data.get('format')!r} unsupported")
    return data


def model_from_checkpoint(data: dict[str, Any]) -> tuple[PhysicalModel, TrainConfig]:
    """Rebuild the trained model (in its training dtype) and its configuration."""
    config = TrainConfig(**data["config"])
    model = build_model(config)
    model.load_state_dict(data["model"])
    return model, config


def _save(path: Path, state: dict[str, Any]) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)  # never leave a half-written checkpoint behind


# ---------------------------------------------------------------- the loop


class WeightAverage:
    """A running mean of a model's weights (tensors only, so it checkpoints with the rest)."""

    def __init__(self) -> None:
        self.mean: dict[str, Tensor] = {}
        self.count = 0

    def add(self, model: PhysicalModel) -> None:
        self.count += 1
        for name, value in model.state_dict().items():
            if name not in self.mean:
                self.mean[name] = value.detach().clone()
            else:
                self.mean[name] += (value.detach() - self.mean[name]) / self.count

    def apply(self, model: PhysicalModel) -> None:
        """Load the mean into the model (nothing if nothing was added)."""
        if self.count:
            model.load_state_dict(self.mean)

    def state(self) -> dict[str, Any] | None:
        return {"mean": self.mean, "count": self.count} if self.count else None

    def restore(self, state: dict[str, Any] | None) -> None:
        if state:
            self.mean, self.count = dict(state["mean"]), int(state["count"])


@dataclass
class TrainResult:
    """What a run ended with."""

    model: PhysicalModel
    config: TrainConfig
    iterations: int
    wall_time: float
    history: list[dict[str, float]]
    checkpoint: Path | None


def _adam_lr(config: TrainConfig, step: int) -> float:
    if config.lr_final is None:  # the published inverse-time decay
        return config.lr / (1.0 + 0.9 * step / 2000.0)
    steps = max(config.adam_iterations - 1, 1)
    return config.lr * (config.lr_final / config.lr) ** (step / steps)


def train(
    config: TrainConfig,
    out_dir: Path | None = None,
    command: str = "",
    resume: bool = False,
    monitor: Monitor | None = None,
    progress: bool = True,
    time_budget: float | None = None,
    until: int | None = None,
) -> TrainResult:
    """Train a model; checkpoints go to ``out_dir/checkpoint.pt`` when ``out_dir`` is given.

    Args:
        config: The run's configuration.
        out_dir: Where the checkpoint goes (None: keep nothing on disk).
        command: The command line that started the run (stored in the checkpoint).
        resume: Continue from ``out_dir/checkpoint.pt`` (same configuration).
        monitor: Called every ``config.monitor_every`` iterations; returns figures to log.
        progress: Show a tqdm progress bar with the loss terms.
        time_budget: Stop after this many seconds of training (None: run all iterations).
        until: Stop after this iteration (a checkpoint is written; ``resume`` continues).
    """
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed + 1)
    model = build_model(config)
    problem = model.problem
    params = list(model.parameters())
    adam = torch.optim.Adam(params, lr=config.lr)
    lbfgs = torch.optim.LBFGS(
        params, lr=1.0, max_iter=1, max_eval=25, history_size=50, line_search_fn="strong_wolfe",
        tolerance_grad=0.0, tolerance_change=0.0,
    )
    start, wall, history = 0, 0.0, []
    average = WeightAverage()
    lbfgs_scale: float | None = None
    checkpoint = out_dir / "checkpoint.pt" if out_dir is not None else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    if resume:
        if checkpoint is None:
            raise UserError("resume needs an output directory")
        data = load_checkpoint(checkpoint)
        if data["config"] != dataclasses.asdict(config):
            raise UserError(f"{checkpoint} was trained with another configuration")
        model.load_state_dict(data["model"])
        adam.load_state_dict(data["adam"])
        if data.get("lbfgs"):
            lbfgs.load_state_dict(data["lbfgs"])
        torch.set_rng_state(data["torch_rng"])
        generator.set_state(data["sampler_rng"])
        start, wall, history = data["iteration"], data["wall_time"], list(data["history"])
        lbfgs_scale = data.get("lbfgs_scale")
        average.restore(data.get("average"))
        command = data.get("command", command)
        logger.info("resumed %s at iteration %d", checkpoint, start)

    def save(iteration: int) -> None:
        if checkpoint is None:
            return
        _save(checkpoint, {
            "format": CHECKPOINT_FORMAT,
            "config": dataclasses.asdict(config),
            "model": model.state_dict(),
            "transform": model.transform_config(),
            "problem": config.problem,
            "parameters": problem.parameters(),
            "iteration": iteration,
            "adam": adam.state_dict(),
            "lbfgs": lbfgs.state_dict() if iteration > config.adam_iterations else None,
            "lbfgs_scale": lbfgs_scale,
            "torch_rng": torch.get_rng_state(),
            "sampler_rng": generator.get_state(),
            "wall_time": wall,
            "command": command,
            "history": history,
            "average": average.state(),
        })

    fine: Collocation | None = None
    bar = _progress_bar(config.iterations, start, progress)
    done = start
    try:
        for iteration in range(start, config.iterations):
            if time_budget is not None and wall >= time_budget:
                break
            if until is not None and iteration >= until:
                break
            began = time.perf_counter()
            if iteration < config.adam_iterations:
                terms = _adam_step(model, adam, config, generator, iteration)
            else:
                lbfgs_done = iteration - config.adam_iterations
                every = config.lbfgs_resample_every
                if fine is None or (every and lbfgs_done and lbfgs_done % every == 0):
                    fine = sample_collocation(problem, config, generator, fine=True)
                    lbfgs.state.clear()
                    lbfgs_scale = None
                if lbfgs_scale is None:
                    lbfgs_scale = 1.0 / max(_total_loss(model, fine, config, generator), 1e-300)
                terms = _lbfgs_step(model, lbfgs, fine, config, generator, lbfgs_scale)
            wall += time.perf_counter() - began
            done = iteration + 1
            record = {"iteration": float(done), "wall_time": wall, **terms}
            if monitor is not None and config.monitor_every and done % config.monitor_every == 0:
                record.update(monitor(model))
                logger.info("iteration %d: %s", done, _fmt(record))
            elif done % 200 == 0:
                logger.info("iteration %d: %s", done, _fmt(record))
            history.append(record)
            if bar is not None:
                bar.update(1)
                bar.set_postfix({k: f"{v:.2e}" for k, v in terms.items()}, refresh=False)
            if done > config.iterations - config.average_window:
                average.add(model)
            if done % config.checkpoint_every == 0:
                save(done)
            if not all(math.isfinite(v) for v in terms.values()):
                raise FloatingPointError(f"loss became {terms} at iteration {done}")
    finally:
        if bar is not None:
            bar.close()
    if done == config.iterations:
        average.apply(model)
    save(done)
    return TrainResult(model, config, done, wall, history, checkpoint)


def _total_loss(
    model: PhysicalModel, points: Collocation, config: TrainConfig, generator: torch.Generator
) -> float:
    state = generator.get_state()
    with torch.no_grad():
        loss = sum(float(v) for v in loss_terms(model, points, config, generator).values())
    generator.set_state(state)
    return loss


def _fmt(record: dict[str, float]) -> str:
    return " ".join(f"{k}={v:.4g}" for k, v in record.items() if k != "iteration")


def _progress_bar(total: int, start: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=start, desc="train", unit="it", dynamic_ncols=True)


def _adam_step(
    model: PhysicalModel,
    adam: torch.optim.Adam,
    config: TrainConfig,
    generator: torch.Generator,
    iteration: int,
) -> dict[str, float]:
    for group in adam.param_groups:
        group["lr"] = _adam_lr(config, iteration)
    points = sample_collocation(model.problem, config, generator)
    adam.zero_grad(set_to_none=True)
    terms = loss_terms(model, points, config, generator)
    loss = sum(terms.values(), torch.zeros(()))
    loss.backward()
    adam.step()
    return {k: float(v.detach()) for k, v in terms.items()}


def _lbfgs_step(
    model: PhysicalModel,
    lbfgs: torch.optim.LBFGS,
    points: Collocation,
    config: TrainConfig,
    generator: torch.Generator,
    loss_scale: float,
) -> dict[str, float]:
    """One L-BFGS iteration on the fixed grid; the objective is the loss times ``loss_scale``.

    The scale brings the objective to O(1): L-BFGS's curvature test (y.s > 1e-10) and its line
    search tolerances are absolute, and at losses near 1e-6 they stop every update.
    """
    # Soft initial terms draw their points inside loss_terms: fix them for L-BFGS's line search.
    state = generator.get_state()
    last: dict[str, float] = {}

    def closure() -> Tensor:
        generator.set_state(state)
        lbfgs.zero_grad(set_to_none=True)
        terms = loss_terms(model, points, config, generator)
        loss = sum(terms.values(), torch.zeros(())) * loss_scale
        loss.backward()
        last.update({k: float(v.detach()) for k, v in terms.items()})
        return loss

    before = [p.detach().clone() for p in model.parameters()]
    lbfgs.step(closure)
    if all(torch.equal(a, p) for a, p in zip(before, model.parameters(), strict=True)):
        # No step taken (its direction was no longer one of descent): restart from the
        # gradient with a fresh curvature history instead of stalling for good.
        logger.debug("L-BFGS stalled; history cleared")
        lbfgs.state.clear()
        lbfgs.step(closure)
    return last
