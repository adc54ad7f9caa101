"""Collocation points: where the residual is evaluated, and the force sampled there.

Our recipes draw a Cartesian grid (per-axis stratified random points, resampled every Adam
step): for a separable model u = A @ B^T on a grid, u_tt = A @ B''^T and Laplacian(u) =
Lap(A) @ B^T cost one small matrix product each. The L-BFGS phase draws one finer grid (L-BFGS
needs a fixed objective). The published configuration scatters (x, t) points instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from membrane_models.learned.training.config import TrainConfig
from membrane_models.problems import ForcedProblem, Problem, time_bump

__all__ = [
    "Collocation",
    "forcing_grid",
    "midpoint_grid",
    "sample_collocation",
    "uniform_points",
]


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
        space = [uniform_points(n, 1.0, generator, dtype) for _ in range(dims)]
        t = uniform_points(n, problem.t_end, generator, dtype)[:, None]
        forcing = _forcing_points(problem, space, t)
        return Collocation(space, t, scattered=True, forcing=forcing)
    ns = config.lbfgs_space_points if fine else config.space_points
    nt = config.lbfgs_time_points if fine else config.time_points
    space = [_stratified(ns, 1.0, generator, dtype) for _ in range(dims)]
    t = _stratified(nt, problem.t_end, generator, dtype)[:, None]
    return Collocation(space, t, forcing=forcing_grid(problem, space, t))


def _stratified(n: int, high: float, generator: torch.Generator, dtype: torch.dtype) -> Tensor:
    """n points in [0, high], one uniform draw per equal cell (covers the ends every time)."""
    jitter = torch.rand(n, generator=generator, dtype=torch.float64)
    return ((torch.arange(n, dtype=torch.float64) + jitter) * (high / n)).to(dtype)


def uniform_points(n: int, high: float, generator: torch.Generator, dtype: torch.dtype) -> Tensor:
    """n independent uniform points in [0, high] (drawn in float64 whatever the dtype)."""
    return (torch.rand(n, generator=generator, dtype=torch.float64) * high).to(dtype)


def forcing_grid(problem: Problem, space: list[Tensor], t: Tensor) -> Tensor:
    """f on the grid (space points flattened, time), shape (n_space, n_t); zero if unforced."""
    if not isinstance(problem, ForcedProblem):
        n = math.prod(s.shape[0] for s in space)
        return torch.zeros(n, t.shape[0], dtype=t.dtype)
    coords = [s.detach().cpu().numpy() for s in space]
    profile = problem.force_profile(np.meshgrid(*coords, indexing="ij")).reshape(-1)
    bump = time_bump(t.detach().cpu().numpy(), problem.a)
    return torch.from_numpy(np.outer(profile, bump)).to(t.dtype)


def _forcing_points(problem: Problem, space: list[Tensor], t: Tensor) -> Tensor:
    """f at scattered points (one space coordinate per axis, one time each); zero if unforced."""
    if not isinstance(problem, ForcedProblem):
        return torch.zeros(t.shape[0], dtype=t.dtype)
    profile = problem.force_profile([s.numpy() for s in space])
    values = profile * time_bump(t[:, 0].numpy(), problem.a)
    return torch.from_numpy(np.asarray(values)).to(t.dtype)


def midpoint_grid(problem: Problem, points: int, dtype: torch.dtype) -> tuple[list[Tensor], Tensor]:
    """A uniform midpoint grid: ``points`` per space axis and in time (the modal projection's)."""
    unit = (torch.arange(points, dtype=dtype) + 0.5) / points
    times = (torch.arange(points, dtype=dtype) + 0.5) * (problem.t_end / points)
    return [unit] * problem.spatial_dims, times
