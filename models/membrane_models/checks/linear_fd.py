"""An independent finite-difference solver, used to check the exact solutions.

Explicit leapfrog, second order in space and time, on the uniform grid of the unit domain
(boundary nodes included and held at zero):

    u^(k+1) = 2 u^k - u^(k-1) + dt^2 (c^2 L_h u^k + f(., t_k)),

with L_h the standard 3-point (string) or 5-point (membrane) Laplacian and the force sampled at
the grid nodes at each time level. The first step is the second-order Taylor start for zero
initial velocity, u^1 = u^0 + dt^2 / 2 (c^2 L_h u^0 + f(., 0)). The time step is the largest
that divides each output interval evenly and keeps c dt / dx <= ``cfl`` / sqrt(d) (leapfrog is
stable up to 1 / sqrt(d)); holding that ratio fixed while refining makes the error O(dx^2).

It shares nothing with the exact solvers but the problem definitions (the initial pluck shape
included), which is the point.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.exact.plucked import pluck_extension
from membrane_models.problems import (
    MembraneForced,
    Problem,
    StringForced,
    StringPlucked,
    time_bump,
)

__all__ = ["FdSolution", "solve_fd"]

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

DEFAULT_CFL = 0.5


@dataclass(frozen=True)
class FdSolution:
    """Grid values from ``solve_fd``: ``u`` shaped (nx, nt) or (nx, ny, nt)."""

    axes: tuple[FloatArray, ...]  # spatial node coordinates
    t: FloatArray
    u: FloatArray
    dt: float


def solve_fd(problem: Problem, n_cells: int, t: ArrayLike, cfl: float = DEFAULT_CFL) -> FdSolution:
    """Leapfrog solution of ``problem`` on ``n_cells`` cells per axis, reported at times ``t``.

    Args:
        problem: a registered problem (string or membrane, forced or plucked).
        n_cells: cells per spatial axis (nodes = n_cells + 1, spacing 1 / n_cells).
        t: output times: 0 and increasing, evenly spaced.
        cfl: target c dt / dx times sqrt(d); the step is this or a little smaller.

    Raises:
        ValueError: bad grid, times or cfl.
    """
    if n_cells < 2:
        raise ValueError(f"n_cells must be >= 2, got {n_cells}")
    if not 0.0 < cfl <= 1.0:
        raise ValueError(f"cfl must lie in (0, 1], got {cfl}")
    times = np.asarray(t, dtype=np.float64)
    if times.ndim != 1 or times.size < 2 or times[0] != 0.0:
        raise ValueError("t must be 1-D, start at 0 and have at least two entries")
    interval = times[1] - times[0]
    if interval <= 0.0 or not np.allclose(np.diff(times), interval, rtol=1e-9, atol=0.0):
        raise ValueError("t must be evenly spaced and increasing")

    d = problem.spatial_dims
    dx = 1.0 / n_cells
    dt_max = cfl * dx / (problem.c * math.sqrt(d))
    substeps = math.ceil(interval / dt_max - 1e-9)
    dt = interval / substeps
    nodes = np.linspace(0.0, 1.0, n_cells + 1)
    axes = (nodes,) * d
    mesh = np.meshgrid(*axes, indexing="ij")
    force = _force_profile(problem, mesh)
    a = getattr(problem, "a", 1.0)

    def source(time: float) -> FloatArray | float:
        if force is None:
            return 0.0
        return force * float(time_bump(time, a))

    u_prev = _initial_shape(problem, mesh)
    u = u_prev + 0.5 * dt**2 * (problem.c**2 * _laplacian(u_prev, dx) + source(0.0))
    _clamp_edges(u)
    out = np.empty((*u.shape, times.size))
    out[..., 0] = u_prev
    step = 1  # u holds level `step`
    total = substeps * (times.size - 1)
    logger.debug("fd %s: %d cells, dt %.3g, %d steps", problem.name, n_cells, dt, total)
    for k in range(1, times.size):
        while step < k * substeps:
            lap = _laplacian(u, dx)
            u_next = 2.0 * u - u_prev + dt**2 * (problem.c**2 * lap + source(step * dt))
            _clamp_edges(u_next)
            u_prev, u = u, u_next
            step += 1
        out[..., k] = u
    return FdSolution(axes=axes, t=times, u=out, dt=dt)


def _force_profile(problem: Problem, mesh: Sequence[FloatArray]) -> FloatArray | None:
    if isinstance(problem, MembraneForced):
        return problem.force_space(mesh[0], mesh[1])
    if isinstance(problem, StringForced):
        return problem.force_space(mesh[0])
    return None


def _initial_shape(problem: Problem, mesh: Sequence[FloatArray]) -> FloatArray:
    if isinstance(problem, StringPlucked):  # the pluck's shape (smoothed: its closed form)
        return pluck_extension(problem, mesh[0])
    return np.zeros(mesh[0].shape)


def _laplacian(u: FloatArray, dx: float) -> FloatArray:
    """Standard second differences on interior nodes; zero on the boundary nodes."""
    lap = np.zeros_like(u)
    inner = tuple(slice(1, -1) for _ in range(u.ndim))
    for axis in range(u.ndim):
        ahead = list(inner)
        behind = list(inner)
        ahead[axis] = slice(2, None)
        behind[axis] = slice(None, -2)
        lap[inner] += u[tuple(ahead)] - 2.0 * u[inner] + u[tuple(behind)]
    return lap / dx**2


def _clamp_edges(u: FloatArray) -> None:
    for axis in range(u.ndim):
        index: list[slice | int] = [slice(None)] * u.ndim
        index[axis] = 0
        u[tuple(index)] = 0.0
        index[axis] = -1
        u[tuple(index)] = 0.0
