"""The output transform: from a separable network to the displacement of a problem.

``PhysicalModel`` wraps a ``SeparableCore`` and turns its factors into physical ones:

    A(x) = S * b(x) * A_net(x)          b = x(1-x) [* y(1-y)]: zero on the whole boundary
    B(t) = (t / t_end)^2 * B_net(t / t_end)   u = u_t = 0 at t = 0 (forced problems)

so u = A @ B^T satisfies the boundary and zero initial conditions exactly and the network only
learns an O(1) shape. S is a characteristic amplitude computed from the problem's parameters
alone: the largest static deflection under the force's peak (forced problems), or the pluck's
height. For the plucked string the initial shape w(x) enters as one more column (A = w, B = 1)
and the time factor is B(t) = E(tau) - E(0) with E(tau) = B_net(tau) + B_net(-tau) even, so
u(x, 0) = w(x) and u_t(x, 0) = 0 hold exactly. (A factor tau^2 there would force B_net to grow
like 1/tau^2 where the pluck's curvature makes the string accelerate at once.)

Inputs and outputs are physical: x in [0, 1]^d, t in [0, t_end], u the displacement.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from membrane_models.learned.networks import Jet, SeparableCore, grid_points
from membrane_models.problems import MembraneForced, Problem, StringForced, StringPlucked
from membrane_models.sines import axis_sines

__all__ = [
    "PhysicalModel",
    "characteristic_amplitude",
    "initial_shape_jet",
]

# Peak of the forcing's time factor 4^a t^(a-1) (1-t)^(a-1), for every a.
TIME_BUMP_PEAK = 4.0


def _static_peak(force: np.ndarray, c: float, dims: int) -> float:
    """max |u| of the static response c^2 Laplacian(u) = -force on the unit square/interval.

    Solved by a sine series on a midpoint grid (a few hundred modes per axis is plenty for a
    scale factor). ``force`` is sampled at the midpoints, shape (N,) or (N, N).
    """
    n = force.shape[0]
    s = (np.arange(n) + 0.5) / n
    k = np.arange(1, n + 1)
    sines = axis_sines(s, n).T  # (modes, points)
    if dims == 1:
        coeffs = 2.0 / n * sines @ force
        u = sines.T @ (coeffs / (c * math.pi * k) ** 2)
    else:
        coeffs = 4.0 / n**2 * sines @ force @ sines.T
        eig = (c * math.pi) ** 2 * (k[:, None] ** 2 + k[None, :] ** 2)
        u = sines.T @ (coeffs / eig) @ sines
    return float(np.max(np.abs(u)))


def characteristic_amplitude(problem: Problem) -> float:
    """The displacement scale S the network's output is multiplied by.

    Forced problems: the largest static deflection under the force at its peak (the true response
    is of this size because the forcing is slow next to the first mode). Plucked string: the
    pluck's height. Falls back to 1 where the parameters give zero.
    """
    if isinstance(problem, StringPlucked):
        amplitude = abs(problem.height)
    elif isinstance(problem, StringForced):
        s = (np.arange(512) + 0.5) / 512
        amplitude = _static_peak(problem.force_space(s) * TIME_BUMP_PEAK, problem.c, 1)
    elif isinstance(problem, MembraneForced):
        s = (np.arange(256) + 0.5) / 256
        force = problem.force_space(s[:, None], s[None, :]) * TIME_BUMP_PEAK
        amplitude = _static_peak(force, problem.c, 2)
    else:
        raise ValueError(f"no characteristic amplitude for problem {problem.name!r}")
    return amplitude if amplitude > 0.0 else 1.0


def _normal_pdf(z: Tensor) -> Tensor:
    return torch.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


def _normal_cdf(z: Tensor) -> Tensor:
    return 0.5 * (1.0 + torch.special.erf(z / math.sqrt(2.0)))


def initial_shape_jet(problem: StringPlucked, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The pluck w(x) with its first and second derivatives, x of shape (n, 1).

    The triangle has kinks at +-x0 (+ 2m) in its odd periodic extension. Smoothing by a Gaussian
    of standard deviation s replaces each kink's ramp by the ramp convolved with the Gaussian:
    ramp * G = s phi(d/s) + d Phi(d/s), a correction local to the kink; the second derivative
    is then jump * phi(d/s) / s instead of a Dirac.
    """
    h, x0, s = problem.height, problem.x0, problem.smoothing
    rising = x <= x0
    value = torch.where(rising, h * x / x0, h * (1.0 - x) / (1.0 - x0))
    first = torch.where(rising, x.new_full((), h / x0), x.new_full((), -h / (1.0 - x0)))
    second = torch.zeros_like(x)
    if s > 0.0:
        jump = h / x0 + h / (1.0 - x0)  # slope decrease at x0, increase at -x0
        for m in (-1, 0, 1):
            for kink, change in ((x0 + 2 * m, -jump), (-x0 + 2 * m, jump)):
                d = x - kink
                z = d / s
                value = value + change * (s * _normal_pdf(z) + d * _normal_cdf(z) - torch.relu(d))
                first = first + change * (_normal_cdf(z) - (d > 0).to(x.dtype))
                second = second + change * _normal_pdf(z) / s
    return value, first, second


class PhysicalModel(nn.Module):
    """A separable network with the problem's output transform: physical in, displacement out.

    Args:
        core: The separable network (normalised inputs).
        problem: The problem it solves (t_end, the pluck's shape).
        scale: Output scale S (see ``characteristic_amplitude``).
        hard_initial: Multiply the time factor by (t/t_end)^2 (u = u_t = 0 at t = 0). Without it,
            the initial conditions are left to the loss (the published training).
    """

    def __init__(
        self, core: SeparableCore, problem: Problem, scale: float, hard_initial: bool = True
    ) -> None:
        super().__init__()
        self.core = core
        self.problem = problem
        self.scale = float(scale)
        self.hard_initial = hard_initial
        self.spatial_dims = problem.spatial_dims
        self.t_end = float(problem.t_end)
        self.plucked = isinstance(problem, StringPlucked)
        self.rank = core.rank + (1 if self.plucked else 0)

    def transform_config(self) -> dict[str, Any]:
        """Plain data describing the output transform (for checkpoints and manifests)."""
        return {
            "scale": self.scale,
            "boundary_factor": "x(1-x)" if self.spatial_dims == 1 else "x(1-x)y(1-y)",
            "time_factor": (
                "E(t/t_end) - E(0), E even"
                if self.plucked
                else "(t/t_end)^2"
                if self.hard_initial
                else "none"
            ),
            "initial_shape_column": self.plucked,
        }

    # ---- plain evaluation (what is exported to ONNX) ----

    def space(self, x: Tensor) -> Tensor:
        """A (n, rank) at points x of shape (n, d)."""
        return self._finish_space(self.core.space(x), x)

    def space_grid(self, axes: Sequence[Tensor]) -> Tensor:
        """A on the Cartesian product of 1-D space coordinates ('ij' order)."""
        return self._finish_space(self.core.space_grid(axes), grid_points(axes))

    def _finish_space(self, net: Tensor, x: Tensor) -> Tensor:
        boundary = torch.prod(x * (1.0 - x), dim=1, keepdim=True)
        a = self.scale * boundary * net
        if self.plucked:
            assert isinstance(self.problem, StringPlucked)
            a = torch.cat([a, initial_shape_jet(self.problem, x[:, :1])[0]], dim=1)
        return a

    def time(self, t: Tensor) -> Tensor:
        """B (m, rank) at times t of shape (m, 1)."""
        tau = t / self.t_end
        if self.plucked:
            core = self.core.time
            b = core(tau) + core(-tau) - 2.0 * core(torch.zeros_like(tau[:1]))
            return torch.cat([b, torch.ones_like(tau)], dim=1)
        b = self.core.time(tau)
        if self.hard_initial:
            b = tau * tau * b
        return b

    def forward(self, xt: Tensor) -> Tensor:
        """u (n, 1) at points (x[, y], t) of shape (n, d + 1)."""
        d = self.spatial_dims
        return torch.sum(self.space(xt[:, :d]) * self.time(xt[:, d:]), dim=1, keepdim=True)

    # ---- with derivatives (training) ----

    def space_grid_jet(self, axes: Sequence[Tensor]) -> Jet:
        """A and its derivatives on the Cartesian product of 1-D space coordinates."""
        return self._finish_space_jet(self.core.space_grid_jet(axes), grid_points(axes))

    def space_jet(self, points: Tensor) -> Jet:
        """A and its derivatives at points of shape (n, d)."""
        return self._finish_space_jet(self.core.space_jet(points), points)

    def _finish_space_jet(self, net: Jet, points: Tensor) -> Jet:
        jet = _times_boundary(net, points, self.scale)
        if self.plucked:
            assert isinstance(self.problem, StringPlucked)
            w, w1, w2 = initial_shape_jet(self.problem, points)
            jet = Jet(
                torch.cat([jet.value, w], 1),
                torch.cat([jet.d1, w1[None]], 2),
                torch.cat([jet.d2, w2[None]], 2),
            )
        return jet

    def time_jet(self, t: Tensor) -> Jet:
        """B and its first and second derivatives with respect to physical time."""
        tau = t / self.t_end
        if self.plucked:
            m = tau.shape[0]
            both = self.core.time_jet(torch.cat([tau, -tau, torch.zeros_like(tau[:1])]))
            plus, minus, zero = slice(0, m), slice(m, 2 * m), slice(2 * m, 2 * m + 1)
            b = both.value[plus] + both.value[minus] - 2.0 * both.value[zero]
            b1 = both.d1[0][plus] - both.d1[0][minus]  # d/dtau of C(-tau) is -C'(-tau)
            b2 = both.d2[0][plus] + both.d2[0][minus]
            b = torch.cat([b, torch.ones_like(tau)], 1)
            b1 = torch.cat([b1, torch.zeros_like(tau)], 1)
            b2 = torch.cat([b2, torch.zeros_like(tau)], 1)
        else:
            net = self.core.time_jet(tau)
            b, b1, b2 = net.value, net.d1[0], net.d2[0]
            if self.hard_initial:
                # (tau^2 C)' = 2 tau C + tau^2 C' ; (tau^2 C)'' = 2 C + 4 tau C' + tau^2 C''
                b, b1, b2 = (
                    tau * tau * b,
                    2 * tau * b + tau * tau * b1,
                    2 * b + 4 * tau * b1 + tau * tau * b2,
                )
        return Jet(b, (b1 / self.t_end)[None], (b2 / self.t_end**2)[None])


def _times_boundary(net: Jet, points: Tensor, scale: float) -> Jet:
    """Jet of S * b(x) * A(x), with b = prod_a x_a (1 - x_a), by the product rule."""
    factors = points * (1.0 - points)  # (n, D)
    b = torch.prod(factors, dim=1, keepdim=True)
    b1, b2 = [], []
    for a in range(points.shape[1]):
        others = torch.prod(torch.cat([factors[:, :a], factors[:, a + 1 :]], 1), 1, keepdim=True)
        b1.append((1.0 - 2.0 * points[:, a : a + 1]) * others)
        b2.append(-2.0 * others)
    d1 = torch.stack(b1)
    d2 = torch.stack(b2)
    return Jet(
        scale * b * net.value,
        scale * (d1 * net.value + b * net.d1),
        scale * (d2 * net.value + 2.0 * d1 * net.d1 + b * net.d2),
    )
