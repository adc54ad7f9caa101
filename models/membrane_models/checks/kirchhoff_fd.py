"""An independent finite-difference solver of the Kirchhoff-Carrier string (a cross-check).

Explicit leapfrog on the uniform grid of [0, 1] (ends held at zero), second order in space and
time:

    u^(j+1) = 2 u^j - u^(j-1) + dt^2 (c^2 + k S_h(u^j)) L_h u^j,
    S_h(u) = sum_i ((u_(i+1) - u_i) / dx)^2 dx,

L_h the 3-point Laplacian; the start is the Taylor step u^1 = u^0 + dt v^0 + dt^2 / 2 (...) u^0.
The step divides each output interval and keeps c_max dt / dx <= ``cfl``, with c_max^2 =
c^2 + k S* the largest tension the energy allows. It shares nothing with the modal solver but the
parameters and the initial shape functions, which is the point: no sines, no ODE solver.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from membrane_models.checks.linear_fd import FdSolution
from membrane_models.exact.kirchhoff_carrier import KirchhoffString
from membrane_models.problems import InvalidProblem

__all__ = ["solve_kirchhoff_fd"]

FloatArray = NDArray[np.float64]
Shape = Callable[[FloatArray], FloatArray]

DEFAULT_CFL = 0.5


def solve_kirchhoff_fd(
    string: KirchhoffString,
    shape: Shape,
    velocity: Shape,
    n_cells: int,
    t: ArrayLike,
    cfl: float = DEFAULT_CFL,
) -> FdSolution:
    """Leapfrog solution on ``n_cells`` cells, reported at the evenly spaced times ``t``.

    Args:
        string: c and k.
        shape: u(x, 0) at an array of points (zero at the ends).
        velocity: u_t(x, 0) at an array of points (zero at the ends).
        n_cells: Cells of the grid (nodes = n_cells + 1).
        t: Output times: 0 first, evenly spaced, increasing.
        cfl: Target c_max dt / dx (leapfrog is stable up to 1).
    """
    times = _checked_times(t)
    if n_cells < 2:
        raise InvalidProblem(f"n_cells must be >= 2, got {n_cells}")
    if not 0.0 < cfl <= 1.0:
        raise InvalidProblem(f"cfl must lie in (0, 1], got {cfl}")
    nodes = np.linspace(0.0, 1.0, n_cells + 1)
    dx = 1.0 / n_cells
    u0 = _clamped(shape(nodes))
    v0 = _clamped(velocity(nodes))

    def tension(u: FloatArray) -> float:
        return string.c**2 + string.k * float(np.sum(np.diff(u) ** 2) / dx)

    energy = 0.5 * float(np.sum(v0**2)) * dx + _potential(string, tension(u0))
    c_max = math.sqrt(string.c**2 + string.k * _largest_stretch(string, energy))
    interval = float(times[1] - times[0])
    substeps = math.ceil(interval * c_max / (cfl * dx) - 1e-9)
    dt = interval / substeps

    u_prev = u0
    u = _clamped(u0 + dt * v0 + 0.5 * dt**2 * tension(u0) * _laplacian(u0, dx))
    out = np.empty((nodes.size, times.size))
    out[:, 0] = u0
    step = 1  # u holds time level `step`
    for j in range(1, times.size):
        while step < j * substeps:
            u_next = 2.0 * u - u_prev + dt**2 * tension(u) * _laplacian(u, dx)
            u_prev, u = u, _clamped(u_next)
            step += 1
        out[:, j] = u
    return FdSolution(axes=(nodes,), t=times, u=out, dt=dt)


def _potential(string: KirchhoffString, tension: float) -> float:
    """c^2 S / 2 + k S^2 / 4, from the tension c^2 + k S."""
    if string.k == 0.0:
        return 0.0  # only bounds the step, and with k = 0 the tension is c^2 whatever S is
    s = (tension - string.c**2) / string.k
    return 0.5 * string.c**2 * s + 0.25 * string.k * s * s


def _largest_stretch(string: KirchhoffString, energy: float) -> float:
    return float(string.stretch_at_energy(energy)) if string.k > 0.0 else 0.0


def _laplacian(u: FloatArray, dx: float) -> FloatArray:
    lap = np.zeros_like(u)
    lap[1:-1] = (u[2:] - 2.0 * u[1:-1] + u[:-2]) / dx**2
    return lap


def _clamped(u: FloatArray) -> FloatArray:
    u = np.array(u, dtype=np.float64)
    u[0] = u[-1] = 0.0
    return u


def _checked_times(t: ArrayLike) -> FloatArray:
    times = np.asarray(t, dtype=np.float64)
    if times.ndim != 1 or times.size < 2 or times[0] != 0.0:
        raise InvalidProblem("t must be 1-D, start at 0 and have at least two entries")
    interval = times[1] - times[0]
    if interval <= 0.0 or not np.allclose(np.diff(times), interval, rtol=1e-9, atol=0.0):
        raise InvalidProblem("t must be evenly spaced and increasing")
    return times
