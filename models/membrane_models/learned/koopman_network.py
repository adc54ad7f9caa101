"""The Koopman latent model of the string (Gin, Lusch, Brunton, Kutz 2021; Lusch et al. 2018).

An autoencoder whose latent coordinates advance by a linear map, z_{k+1} = K(z) z_k:

- **outer encoder** (residual): w = (u, u_t) on the 128 points, scaled; v = w + N(w) - N(0),
  N a ReLU network of 4 hidden layers. Subtracting N(0) keeps the rest state at the origin,
  and near it the map is linear (no ReLU changes sign), so small motions stay linear.
- **inner encoder**: linear, v -> z (no bias), ``pairs`` complex pairs plus one invariant.
- **step**: each pair (a_j, b_j) turns by the angle theta_j; the invariant (eigenvalue 1) is
  kept. The eigenvalues exp(+-i theta_j) have modulus exactly 1: the string conserves its
  energy, and any modulus below 1 would compound over 10^5 steps (0.99999^100000 = e^-1).
- **auxiliary network** (the ``aux`` variant): theta_j = dt w_j exp(g_j(f) - g_j(0)), f the
  pairs' squared radii (scaled to nonlinearity units) and the invariant. A rotation keeps the
  radii and the invariant, so the frequencies are constant along a step sequence, as the
  nonlinear string's amplitude-dependent frequencies are; the ``fixed`` variant has g = 0.
- **inner and outer decoders** mirror the encoders.

Initialisation makes the network the linear modal model of its first ``pairs`` modes: the inner
encoder projects onto sin(n pi x) (latent a_n = n q_n, b_n = p_n / pi in units of ``scale``),
w_j = j pi c, the residual branches start at zero. Training moves it from there.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import Tensor, nn

__all__ = ["VARIANTS", "KoopmanConfig", "KoopmanNetwork"]

VARIANTS = ("aux", "fixed")


@dataclass(frozen=True)
class KoopmanConfig:
    """The network's shape and the physics it is initialised from.

    Attributes:
        points: Interior points of a snapshot (u and u_t each).
        pairs: Complex-conjugate latent pairs (state size 2 pairs, plus the invariant).
        width: Hidden width of the outer encoder and decoder.
        hidden_layers: Hidden layers of each outer network (the study's 4).
        aux_width: Hidden width of the auxiliary network (2 tanh layers).
        variant: ``aux`` (frequencies from the amplitudes) or ``fixed`` (a fixed spectrum).
        dt: The step.
        c: Wave speed (initial frequencies j pi c).
        k: Stretch coefficient (scales the auxiliary network's inputs to nonlinearity units).
        scale: Displacement unit of the scaled inputs.
    """

    points: int = 128
    pairs: int = 10
    width: int = 128
    hidden_layers: int = 4
    aux_width: int = 64
    variant: str = "aux"
    dt: float = 0.01
    c: float = 1.0
    k: float = 100.0
    scale: float = 0.01

    @property
    def latent(self) -> int:
        """State size: two per pair and the invariant."""
        return 2 * self.pairs + 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _mlp(inputs: int, width: int, layers: int, outputs: int, act: type[nn.Module]) -> nn.Sequential:
    modules: list[nn.Module] = []
    size = inputs
    for _ in range(layers):
        modules += [nn.Linear(size, width), act()]
        size = width
    last = nn.Linear(size, outputs)
    nn.init.zeros_(last.weight)  # the residual branch starts at zero: the modal model
    nn.init.zeros_(last.bias)
    return nn.Sequential(*modules, last)


class _Residual(nn.Module):
    """x + N(x) - N(0): a residual map that keeps the origin."""

    def __init__(self, size: int, width: int, layers: int) -> None:
        super().__init__()
        self.net = _mlp(size, width, layers, size, nn.ReLU)

    def forward(self, x: Tensor) -> Tensor:
        zero = torch.zeros_like(x[:1])
        out: Tensor = x + self.net(x) - self.net(zero)
        return out


class KoopmanNetwork(nn.Module):
    """Encoder, step and decoder of the Koopman latent model (see the module docstring)."""

    unit: Tensor
    kept: Tensor
    sine_coefficients: Tensor
    wavenumbers: Tensor

    def __init__(self, config: KoopmanConfig) -> None:
        super().__init__()
        if config.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {VARIANTS}, got {config.variant!r}")
        self.config = config
        n, p = config.points, config.pairs
        x = torch.arange(1, n + 1, dtype=torch.float64) / (n + 1)
        modes = torch.arange(1, p + 1, dtype=torch.float64)
        sines = torch.sin(math.pi * torch.outer(modes, x))  # (pairs, points)
        unit = torch.cat([torch.full((n,), config.scale), torch.full((n,), config.scale * math.pi)])
        self.register_buffer("unit", unit.float())
        # The first ``pairs`` sine modes' share of a scaled state (u and u_t alike): what a
        # state of size 2 pairs can hold of the linear string, the training's targets.
        kept = (2.0 / (n + 1) * sines.T @ sines).float()
        self.register_buffer("kept", torch.block_diag(kept, kept))
        every = torch.arange(1, n + 1, dtype=torch.float64)
        dst = 2.0 / (n + 1) * torch.sin(math.pi * torch.outer(x, every))  # points -> modes
        self.register_buffer("sine_coefficients", dst.float())
        self.register_buffer("wavenumbers", (math.pi * every).float())
        self.outer_encoder = _Residual(2 * n, config.width, config.hidden_layers)
        self.outer_decoder = _Residual(2 * n, config.width, config.hidden_layers)
        self.inner_encoder = nn.Linear(2 * n, config.latent, bias=False)
        self.inner_decoder = nn.Linear(config.latent, 2 * n, bias=False)
        enc = torch.zeros(config.latent, 2 * n, dtype=torch.float64)
        dec = torch.zeros(2 * n, config.latent, dtype=torch.float64)
        project = 2.0 / (n + 1) * sines  # discrete sine coefficients on the interior points
        enc[0 : 2 * p : 2, :n] = modes[:, None] * project  # a_n = n q_n
        enc[1 : 2 * p : 2, n:] = project  # b_n = p_n / pi
        dec[:n, 0 : 2 * p : 2] = (sines / modes[:, None]).T
        dec[n:, 1 : 2 * p : 2] = sines.T
        with torch.no_grad():
            self.inner_encoder.weight.copy_(enc.float())
            self.inner_decoder.weight.copy_(dec.float())
        self.log_frequency = nn.Parameter(torch.log(math.pi * config.c * modes).float())
        self.aux = _mlp(p + 1, config.aux_width, 2, p, nn.Tanh)
        # Squared radius -> that pair's share of the nonlinearity k S* / c^2 (linear estimate).
        self.nonlinearity_unit = config.k * (math.pi * config.scale) ** 2 / (2.0 * config.c**4)

    # ------------------------------------------------------------ parts

    def truncate(self, scaled: Tensor) -> Tensor:
        """A scaled state's first ``pairs`` sine modes (the training targets)."""
        out: Tensor = scaled @ self.kept
        return out

    def outer(self, state: Tensor) -> Tensor:
        """(n, 2 points) of (u, u_t) -> v, the outer encoder's output."""
        out: Tensor = self.outer_encoder(state / self.unit)
        return out

    def encode(self, state: Tensor) -> Tensor:
        """(n, 2 points) of (u, u_t) -> latent z (n, latent)."""
        out: Tensor = self.inner_encoder(self.outer(state))
        return out

    def inner_decode(self, z: Tensor) -> Tensor:
        out: Tensor = self.inner_decoder(z)
        return out

    def decode(self, z: Tensor) -> Tensor:
        """Latent (n, latent) -> (u, u_t) (n, 2 points)."""
        out: Tensor = self.outer_decoder(self.inner_decoder(z)) * self.unit
        return out

    def angles(self, z: Tensor) -> Tensor:
        """theta_j per state (n, pairs): the step's rotation angles."""
        p = self.config.pairs
        base = self.config.dt * torch.exp(self.log_frequency)
        if self.config.variant == "fixed":
            return base.expand(z.shape[0], p)
        radii = z[:, 0 : 2 * p : 2] ** 2 + z[:, 1 : 2 * p : 2] ** 2
        features = torch.cat([radii * self.nonlinearity_unit, z[:, 2 * p :]], dim=1)
        shift = self.aux(features) - self.aux(torch.zeros_like(features[:1]))
        out: Tensor = base * torch.exp(shift)
        return out

    def advance(self, z: Tensor, steps: Tensor | float = 1.0) -> Tensor:
        """K(z)^m z for ``steps`` m (a number or (n, 1)): each pair turned by m theta_j."""
        return self.turn(z, self.angles(z) * steps)

    def turn(self, z: Tensor, angle: Tensor) -> Tensor:
        """Each pair of z turned by its own ``angle`` (n, pairs); the invariant kept."""
        p = self.config.pairs
        cos, sin = torch.cos(angle), torch.sin(angle)
        a, b = z[:, 0 : 2 * p : 2], z[:, 1 : 2 * p : 2]
        pairs = torch.stack([a * cos + b * sin, b * cos - a * sin], dim=2)
        return torch.cat([pairs.reshape(z.shape[0], 2 * p), z[:, 2 * p :]], dim=1)

    def energy(self, scaled: Tensor) -> Tensor:
        """The string's energy of scaled states (n, 2 points), from their sine series."""
        n = self.config.points
        physical = scaled * self.unit
        q = physical[:, :n] @ self.sine_coefficients
        p = physical[:, n:] @ self.sine_coefficients
        stretch = 0.5 * torch.sum((self.wavenumbers * q) ** 2, dim=1)
        c2, k = self.config.c**2, self.config.k
        out: Tensor = 0.25 * torch.sum(p * p, dim=1) + 0.5 * c2 * stretch + 0.25 * k * stretch**2
        return out

    def step_matrix(self, z: Tensor) -> Tensor:
        """K(z) for one state z (latent,): block-diagonal rotations and the invariant's 1."""
        theta = self.angles(z[None])[0]
        k = torch.eye(self.config.latent, dtype=z.dtype)
        for j, angle in enumerate(theta):
            c, s = torch.cos(angle), torch.sin(angle)
            k[2 * j, 2 * j], k[2 * j, 2 * j + 1] = c, s
            k[2 * j + 1, 2 * j], k[2 * j + 1, 2 * j + 1] = -s, c
        return k

    def forward(self, state: Tensor) -> Tensor:
        """One step from (u, u_t): decode(K encode(state))."""
        return self.decode(self.advance(self.encode(state)))
