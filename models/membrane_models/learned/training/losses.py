"""The loss: the PDE residual, its modal term, and soft initial conditions.

Our recipes' loss is the PDE residual alone (boundary and initial conditions are exact by
construction, see ``transforms``), plus the ``modal`` term: the displacement error that the
residual's low sine modes cause. The published configuration enforces the initial conditions
softly and adds their terms. No solution data enters any term.
"""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from membrane_models.learned.training.collocation import (
    Collocation,
    forcing_grid,
    midpoint_grid,
    uniform_points,
)
from membrane_models.learned.training.config import TrainConfig
from membrane_models.learned.transforms import TIME_BUMP_PEAK, PhysicalModel, initial_shape_jet
from membrane_models.problems import ForcedProblem, Problem, StringPlucked

__all__ = [
    "kink_coefficients",
    "kink_series",
    "loss_terms",
    "modal_term",
    "projected_residual",
    "residual_scale",
    "sine_coefficients",
]


def residual_scale(model: PhysicalModel, config: TrainConfig) -> float:
    """The residual's characteristic size, so that the loss starts near 1."""
    if not config.output_scaling:
        return 1.0
    problem = model.problem
    if isinstance(problem, StringPlucked):
        return problem.c**2 * model.scale * math.pi**2
    if isinstance(problem, ForcedProblem):
        return TIME_BUMP_PEAK * abs(problem.h) or 1.0
    raise TypeError(f"no residual scale for {type(problem).__name__}")


def loss_terms(
    model: PhysicalModel, points: Collocation, config: TrainConfig, generator: torch.Generator
) -> dict[str, Tensor]:
    """The loss terms: mean squared scaled residual, the modal term, soft initial conditions."""
    c2 = model.problem.c**2
    scale = residual_scale(model, config)
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
    kink = kink_series(model, config.kink_modes, points) if config.kink_modes else None
    pointwise = residual if kink is None else residual + kink
    terms = {"residual": torch.mean((pointwise / scale) ** 2)}
    if config.modal_modes and not points.scattered:
        if config.modal_points:
            coeffs, wavenumber, times = projected_residual(
                model, config.modal_modes, config.modal_points
            )
        else:
            coeffs, wavenumber = sine_coefficients(residual, points.space, config.modal_modes)
            singular = kink_coefficients(model.problem, config.modal_modes, residual.dtype)
            if singular is not None:
                coeffs = coeffs + singular[:, None]
            times = points.time
        terms["modal"] = config.modal_weight * modal_term(
            coeffs, wavenumber, times, math.sqrt(c2), model.scale
        )
    if not config.hard_initial:
        terms.update(_initial_terms(model, config, generator))
    return terms


def sine_coefficients(grid: Tensor, space: list[Tensor], modes: int) -> tuple[Tensor, Tensor]:
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


def projected_residual(
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
    axes, times = midpoint_grid(problem, points, dtype)
    a, wavenumber = sine_coefficients(model.space_grid(axes), axes, modes)
    kink = kink_coefficients(problem, modes, dtype)
    if kink is not None:
        a = torch.cat([a[:, :-1], (kink / (c2 * (math.pi * wavenumber) ** 2))[:, None]], 1)
    jet = model.time_jet(times[:, None])
    coeffs = a @ jet.d2[0].T + (c2 * (math.pi * wavenumber) ** 2)[:, None] * (a @ jet.value.T)
    if isinstance(problem, ForcedProblem):
        coeffs = coeffs - _forcing_coefficients(problem, modes, points, dtype)
    return coeffs, wavenumber, times[:, None]


@functools.lru_cache(maxsize=4)
def _forcing_coefficients(problem: Problem, modes: int, points: int, dtype: torch.dtype) -> Tensor:
    """f's sine coefficients on ``projected_residual``'s grid (fixed, so computed once)."""
    axes, times = midpoint_grid(problem, points, dtype)
    return sine_coefficients(forcing_grid(problem, axes, times), axes, modes)[0]


def kink_coefficients(problem: Problem, modes: int, dtype: torch.dtype) -> Tensor | None:
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
    return -(problem.c**2) * 2.0 * weight * torch.sin(math.pi * n * problem.x0)


def kink_series(model: PhysicalModel, modes: int, points: Collocation) -> Tensor | None:
    """The Dirac part's first ``modes`` sine modes at the grid's space points, shape (n, 1).

    Added to the pointwise residual, it makes that residual agree with the modal term: without
    it the pointwise residual is smallest for a string that never leaves the triangle, and it
    held every mode the modal term does not outweigh (above about 20) frozen there.
    """
    coeffs = kink_coefficients(model.problem, modes, points.time.dtype)
    if coeffs is None or points.scattered:
        return None
    n = torch.arange(1, modes + 1, dtype=coeffs.dtype)
    x = points.space[0]
    return torch.sin(math.pi * x[:, None] * n[None, :]) @ coeffs[:, None]


def modal_term(coeffs: Tensor, wavenumber: Tensor, t: Tensor, c: float, amplitude: float) -> Tensor:
    """The displacement error that the residual's low sine modes cause, relative to S.

    With u = u_exact + e, the error obeys the same wave equation driven by the residual:
    e_tt - c^2 Laplacian(e) = r, e = e_t = 0 at t = 0. Per sine mode n (angular frequency
    w_n = c pi |n|) that is Duhamel's integral e_n(t) = int_0^t sin(w_n (t - s)) / w_n r_n(s) ds.
    A low mode's residual is small for a large error (and a resonant one keeps growing), so the
    mean-square residual hardly sees the error that dominates the relative L2 norm; this term
    measures that error directly: mean (e_n(t_j) / S)^2 over the modes of ``coeffs`` (the
    residual's sine coefficients, (modes, n_t), see ``sine_coefficients`` and
    ``kink_coefficients``, or ``projected_residual``) and the time points. It is the residual
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
        [
            uniform_points(config.initial_points, 1.0, generator, dtype)
            for _ in range(model.spatial_dims)
        ],
        1,
    )
    t0 = torch.zeros(1, 1, dtype=dtype)
    jet = model.time_jet(t0)
    a = model.space(x)
    u0 = a @ jet.value[0]
    ut0 = a @ jet.d1[0][0]
    target = torch.zeros_like(u0)
    if isinstance(model.problem, StringPlucked):
        target = initial_shape_jet(model.problem, x[:, :1])[0][:, 0]
    norm = model.scale
    return {
        "initial": torch.mean(((u0 - target) / norm) ** 2),
        "velocity": torch.mean((ut0 * model.t_end / norm) ** 2),
    }
