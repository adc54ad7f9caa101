"""Networks whose output factors as u(x, t) = sum_k A_k(x) B_k(t).

Two families, one interface (``SeparableCore``):

- ``SeparablePINN``: one small MLP per axis (Cho et al. 2023, SPINN). The spatial factor is the
  product of the per-axis outputs, A_k(x, y) = X_k(x) Y_k(y); the time factor is T_k(t).
- ``STMsFFN``: the published spatio-temporal multi-scale Fourier feature network (Wang, Wang &
  Perdikaris 2021). Its spatial and temporal branches meet in an elementwise product before a
  linear head, so it factors too: A = head weights times spatial features, B = temporal features.

Each network is built from its typed configuration (``architectures``); ``config()`` returns the
plain form a manifest shows, which ``core_from_config`` rebuilds.

Second derivatives are propagated forward through the layers as jets (value, d/ds, d2/ds2 per
input direction) instead of by nested autograd: every layer here is elementwise or linear, so the
chain rule is a few tensor operations and the parameter gradients flow through them as usual.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from membrane_models.learned.architectures import (
    ArchConfig,
    FourierSpec,
    GaussianFeatures,
    HarmonicFeatures,
    SpinnConfig,
    StmsffnConfig,
    arch_from_dict,
)

__all__ = [
    "ARCHITECTURES",
    "AxisNetwork",
    "FourierFeatures",
    "Jet",
    "STMsFFN",
    "SeparableCore",
    "SeparablePINN",
    "TanhMLP",
    "build_core",
    "core_from_config",
]


@dataclass
class Jet:
    """A batch of values with first and second derivatives along each input direction.

    Attributes:
        value: (n, w) values.
        d1: (D, n, w) first derivatives, one slice per input direction.
        d2: (D, n, w) second (pure) derivatives, one slice per input direction.
    """

    value: Tensor
    d1: Tensor
    d2: Tensor

    @classmethod
    def seed(cls, x: Tensor) -> Jet:
        """The jet of the inputs themselves: d x_a / d x_b = delta_ab, second derivatives zero."""
        n, dims = x.shape
        eye = torch.eye(dims, dtype=x.dtype, device=x.device)
        d1 = eye[:, None, :].expand(dims, n, dims)
        return cls(x, d1, torch.zeros_like(d1))

    def laplacian(self) -> Tensor:
        """Sum of the pure second derivatives over the input directions, (n, w)."""
        return self.d2.sum(dim=0)


class FourierFeatures(nn.Module):
    """Fixed embedding s -> [a cos(s B), a sin(s B)] (optionally with s itself first).

    Args:
        frequencies: (in_dim, m) matrix B, stored as a buffer (never trained).
        include_input: Prepend the raw input to the features.
        amplitudes: (m,) weights a of the feature pairs (default 1): decaying weights start the
            network smooth, so that its high harmonics are learned, not inherited from the
            random initialisation.
    """

    frequencies: Tensor
    amplitudes: Tensor

    def __init__(
        self, frequencies: Tensor, include_input: bool = False, amplitudes: Tensor | None = None
    ) -> None:
        super().__init__()
        self.register_buffer("frequencies", frequencies.clone())
        if amplitudes is None:
            amplitudes = torch.ones(frequencies.shape[1], dtype=frequencies.dtype)
        self.register_buffer("amplitudes", amplitudes.clone())
        self.include_input = include_input
        self.in_dim = int(frequencies.shape[0])
        self.out_dim = 2 * int(frequencies.shape[1]) + (self.in_dim if include_input else 0)

    def forward(self, x: Tensor) -> Tensor:
        z = x @ self.frequencies
        parts = [self.amplitudes * torch.cos(z), self.amplitudes * torch.sin(z)]
        if self.include_input:
            parts.insert(0, x)
        return torch.cat(parts, dim=-1)

    def jet(self, x: Jet) -> Jet:
        """Propagate a jet whose value is the raw input (the embedding is the first layer)."""
        b: Tensor = self.frequencies
        z = x.value @ b
        cos, sin = self.amplitudes * torch.cos(z), self.amplitudes * torch.sin(z)
        # d/dx_a of cos(x . b_m) = -sin(z) b_am; the second derivative multiplies by b_am again.
        ba = b[:, None, :]
        value = [cos, sin]
        d1 = [-sin[None] * ba, cos[None] * ba]
        d2 = [-cos[None] * ba**2, -sin[None] * ba**2]
        if self.include_input:
            value.insert(0, x.value)
            d1.insert(0, x.d1)
            d2.insert(0, x.d2)
        return Jet(torch.cat(value, -1), torch.cat(d1, -1), torch.cat(d2, -1))


class TanhMLP(nn.Module):
    """Dense layers with tanh between them and a linear last layer.

    Args:
        sizes: Layer widths, input first, output last (e.g. [1, 64, 64, 32]).
        final_activation: Apply tanh after the last layer too.
    """

    def __init__(self, sizes: Sequence[int], final_activation: bool = False) -> None:
        super().__init__()
        linears = [nn.Linear(a, b) for a, b in itertools.pairwise(sizes)]
        for layer in linears:
            nn.init.xavier_normal_(layer.weight)
            nn.init.zeros_(layer.bias)
        self.layers = nn.ModuleList(linears)
        self.final_activation = final_activation

    def _activated(self, index: int) -> bool:
        return index < len(self.layers) - 1 or self.final_activation

    def forward(self, x: Tensor) -> Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if self._activated(i):
                x = torch.tanh(x)
        return x

    def jet(self, x: Jet) -> Jet:
        """Propagate values and per-direction first and second derivatives."""
        for i, layer in enumerate(self.layers):
            assert isinstance(layer, nn.Linear)
            w = layer.weight.T
            x = Jet(layer(x.value), x.d1 @ w, x.d2 @ w)
            if self._activated(i):
                s = torch.tanh(x.value)
                ds = 1.0 - s * s  # tanh' ; tanh'' = -2 s tanh'
                x = Jet(s, ds * x.d1, ds * x.d2 - 2.0 * s * ds * x.d1 * x.d1)
        return x


class AxisNetwork(nn.Module):
    """An MLP over a few inputs, optionally behind a Fourier embedding; maps (n, d) -> (n, out).

    Args:
        embedding: The Fourier embedding of the input (None: the raw input).
        sizes: The MLP's layer widths, the embedding's width first.
        skip: Add a linear map from the embedding straight to the output, starting at zero.
            Through tanh layers a high harmonic is hard to reach (an MLP learns low frequencies
            first); the skip path makes every harmonic of the embedding one weight away.
    """

    def __init__(
        self, embedding: FourierFeatures | None, sizes: Sequence[int], skip: bool = False
    ) -> None:
        super().__init__()
        self.embedding = embedding
        self.mlp = TanhMLP(sizes)
        self.skip: nn.Linear | None = None
        if skip:
            self.skip = nn.Linear(sizes[0], sizes[-1], bias=False)
            nn.init.zeros_(self.skip.weight)

    def forward(self, x: Tensor) -> Tensor:
        features = self.embedding(x) if self.embedding is not None else x
        out: Tensor = self.mlp(features)
        if self.skip is not None:
            out = out + self.skip(features)
        return out

    def jet(self, x: Tensor) -> Jet:
        seed = Jet.seed(x)
        features = self.embedding.jet(seed) if self.embedding is not None else seed
        out = self.mlp.jet(features)
        if self.skip is not None:
            w = self.skip.weight.T
            out = Jet(
                out.value + features.value @ w, out.d1 + features.d1 @ w, out.d2 + features.d2 @ w
            )
        return out


class SeparableCore(nn.Module):
    """Interface of a separable network on normalised inputs (space in [0,1]^d, time in [0,1]).

    ``space(x)`` returns A (n, r), ``time(t)`` returns B (m, r); u = A @ B^T. The jet variants
    add the first and second derivatives along each input direction, which the PDE residual and
    the output transform's product rule need.
    """

    rank: int
    spatial_dims: int

    def space(self, x: Tensor) -> Tensor:
        raise NotImplementedError

    def space_jet(self, x: Tensor) -> Jet:
        """A with its derivatives at points x of shape (n, d)."""
        raise NotImplementedError

    def space_grid(self, axes: Sequence[Tensor]) -> Tensor:
        """A on the Cartesian product of 1-D coordinates ('ij' order)."""
        return self.space(grid_points(axes))

    def space_grid_jet(self, axes: Sequence[Tensor]) -> Jet:
        """A with its derivatives on the Cartesian product of 1-D coordinates ('ij' order)."""
        return self.space_jet(grid_points(axes))

    def time(self, t: Tensor) -> Tensor:
        raise NotImplementedError

    def time_jet(self, t: Tensor) -> Jet:
        """B with its first and second derivatives at times t of shape (m, 1)."""
        raise NotImplementedError

    def config(self) -> dict[str, Any]:
        """Plain-data hyperparameters that rebuild this network with ``core_from_config``."""
        raise NotImplementedError


def _fourier(in_dim: int, spec: FourierSpec, generator: torch.Generator) -> FourierFeatures:
    """A Fourier embedding: harmonic (k pi, k = 1..m, weights k^-decay) or Gaussian
    (frequencies drawn from N(0, sigma^2) with the network's generator)."""
    m = spec.features
    amplitudes = None
    if isinstance(spec, HarmonicFeatures):
        k = torch.arange(1, m + 1, dtype=torch.float64)
        b = math.pi * k.repeat(in_dim, 1)
        amplitudes = k ** -float(spec.decay)
    else:
        assert isinstance(spec, GaussianFeatures)
        b = float(spec.sigma) * torch.randn(in_dim, m, generator=generator, dtype=torch.float64)
    return FourierFeatures(b, include_input=spec.include_input, amplitudes=amplitudes)


class SeparablePINN(SeparableCore):
    """Per-axis MLPs: u = sum_k X_k(x) [Y_k(y)] T_k(t) (SPINN).

    Args:
        spatial_dims: 1 (string) or 2 (membrane).
        arch: Rank, widths, embeddings and skip paths (``architectures.SpinnConfig``).
        seed: Seed of the (random) Fourier frequencies and of the initial weights.
    """

    def __init__(self, spatial_dims: int, arch: SpinnConfig, seed: int = 0) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        torch.manual_seed(seed)
        self.spatial_dims = spatial_dims
        self.rank = arch.rank
        self.arch = arch
        self.seed = seed
        sizes = [arch.width] * arch.depth + [arch.rank]

        def axis(features: FourierSpec | None) -> AxisNetwork:
            embedding = _fourier(1, features, generator) if features else None
            first = embedding.out_dim if embedding is not None else 1
            return AxisNetwork(embedding, [first, *sizes], skip=arch.skip)

        self.space_axes = nn.ModuleList(axis(arch.space_features) for _ in range(spatial_dims))
        self.time_axis = axis(arch.time_features)

    def config(self) -> dict[str, Any]:
        plain = self.arch.to_dict()
        skip = {"skip": plain.pop("skip")} if "skip" in plain else {}
        # The manifests' key order: name, spatial_dims, the architecture, seed (then skip).
        return {
            "name": plain.pop("name"),
            "spatial_dims": self.spatial_dims,
            **plain,
            "seed": self.seed,
            **skip,
        }

    def space(self, x: Tensor) -> Tensor:
        a: Tensor = self.space_axes[0](x[:, 0:1])
        for i in range(1, self.spatial_dims):
            a = a * self.space_axes[i](x[:, i : i + 1])
        return a

    def space_jet(self, x: Tensor) -> Jet:
        jets = [_axis(net).jet(x[:, i : i + 1]) for i, net in enumerate(self.space_axes)]
        return _product_of_axes(jets, lambda a, b: a * b)

    def space_grid(self, axes: Sequence[Tensor]) -> Tensor:
        values = [net(s[:, None]) for net, s in zip(self.space_axes, axes, strict=True)]
        return functools.reduce(_outer_rows, values)

    def space_grid_jet(self, axes: Sequence[Tensor]) -> Jet:
        # Each axis network runs on its own 1-D coordinates only: the point of SPINN.
        jets = [_axis(net).jet(s[:, None]) for net, s in zip(self.space_axes, axes, strict=True)]
        if self.spatial_dims == 1:
            return jets[0]
        return _product_of_axes(jets, _outer_rows)

    def time(self, t: Tensor) -> Tensor:
        out: Tensor = self.time_axis(t)
        return out

    def time_jet(self, t: Tensor) -> Jet:
        jet: Jet = self.time_axis.jet(t)
        return jet


def grid_points(axes: Sequence[Tensor]) -> Tensor:
    """The Cartesian product of 1-D coordinates as points (n, d), 'ij' order."""
    mesh = torch.meshgrid(*axes, indexing="ij")
    return torch.stack([m.reshape(-1) for m in mesh], dim=1)


def _outer_rows(a: Tensor, b: Tensor) -> Tensor:
    """Every row of a times every row of b, (n, r) and (m, r) -> (n m, r) in 'ij' order."""
    return (a[:, None, :] * b[None, :, :]).reshape(-1, a.shape[-1])


def _axis(module: nn.Module) -> AxisNetwork:
    assert isinstance(module, AxisNetwork)
    return module


def _embedding(module: nn.Module) -> FourierFeatures:
    assert isinstance(module, FourierFeatures)
    return module


def _product_of_axes(jets: Sequence[Jet], combine: Callable[[Tensor, Tensor], Tensor]) -> Jet:
    """Jet of a product of one-variable factors, one per direction (``combine`` multiplies two).

    The derivative along direction a touches only factor a: d_a(X Y) = X' Y for a = x.
    """
    value = jets[0].value
    for j in jets[1:]:
        value = combine(value, j.value)
    d1: list[Tensor] = []
    d2: list[Tensor] = []
    for a in range(len(jets)):
        parts = [j.value for j in jets]
        for order, out in ((1, d1), (2, d2)):
            parts[a] = (jets[a].d1 if order == 1 else jets[a].d2)[0]
            prod = parts[0]
            for p in parts[1:]:
                prod = combine(prod, p)
            out.append(prod)
    return Jet(value, torch.stack(d1), torch.stack(d2))


class STMsFFN(SeparableCore):
    """Spatio-temporal multi-scale Fourier feature network (Wang, Wang & Perdikaris 2021).

    One Gaussian Fourier embedding per sigma, a tanh MLP per embedding (one MLP for all of them
    when ``shared``), every spatial branch multiplied elementwise with every temporal branch, and
    a linear head over the concatenated products. Layer sizes as published: ``[d+1] +
    [width] * hidden + [1]``; the embedding has ``width`` features (width/2 cos, width/2 sin).

    Separable form: with H^x_i (n, w) and H^t_j (m, w) the branch outputs and W the head,
    u = sum_{i,j,c} W_{ijc} H^x_{ic}(x) H^t_{jc}(t) + b, so A = [W_{ijc} H^x_{ic}, b] and
    B = [H^t_{jc}, 1] (rank n_x * n_t * w + 1).
    """

    def __init__(self, spatial_dims: int, arch: StmsffnConfig, seed: int = 0) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        torch.manual_seed(seed)
        self.spatial_dims = spatial_dims
        self.arch = arch
        self.seed = seed
        width, hidden, shared = arch.width, arch.hidden, arch.shared
        sigmas_x, sigmas_t = arch.sigmas_x, arch.sigmas_t
        self.width = width

        def embed(dim: int, sigma: float) -> FourierFeatures:
            b = sigma * torch.randn(dim, width // 2, generator=generator, dtype=torch.float64)
            return FourierFeatures(b, include_input=False)

        self.embed_x = nn.ModuleList(embed(spatial_dims, s) for s in sigmas_x)
        self.embed_t = nn.ModuleList(embed(1, s) for s in sigmas_t)
        # `hidden` hidden layers: the embedding is the first, then hidden - 1 dense tanh layers.
        sizes = [width] * hidden
        n_branches = 1 if shared else len(sigmas_x) + len(sigmas_t)
        self.mlps = nn.ModuleList(TanhMLP(sizes, final_activation=True) for _ in range(n_branches))
        self.shared = shared
        self.head = nn.Linear(len(sigmas_x) * len(sigmas_t) * width, 1)
        nn.init.xavier_normal_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.rank = len(sigmas_x) * len(sigmas_t) * width + 1

    def config(self) -> dict[str, Any]:
        plain = self.arch.to_dict()
        return {"name": plain.pop("name"), "spatial_dims": self.spatial_dims, **plain,
                "seed": self.seed}  # fmt: skip

    def _mlp(self, branch: int) -> TanhMLP:
        mlp = self.mlps[0 if self.shared else branch]
        assert isinstance(mlp, TanhMLP)
        return mlp

    def _head_blocks(self, spatial: Sequence[Tensor]) -> Tensor:
        """A's network columns: each spatial branch repeated per temporal branch, times W."""
        n_t = len(self.embed_t)
        weight = self.head.weight.reshape(len(spatial), n_t, self.width)
        blocks = [h[:, None, :] * weight[i][None] for i, h in enumerate(spatial)]
        return torch.stack(blocks, dim=1).reshape(spatial[0].shape[0], -1)

    def _bias_column(self, n: int, like: Tensor) -> Tensor:
        return self.head.bias.to(like.dtype).expand(n, 1)

    def space(self, x: Tensor) -> Tensor:
        branches = [self._mlp(i)(e(x)) for i, e in enumerate(self.embed_x)]
        return torch.cat([self._head_blocks(branches), self._bias_column(x.shape[0], x)], 1)

    def space_jet(self, x: Tensor) -> Jet:
        seed = Jet.seed(x)
        jets = [self._mlp(i).jet(_embedding(e).jet(seed)) for i, e in enumerate(self.embed_x)]
        n = x.shape[0]
        value = torch.cat([self._head_blocks([j.value for j in jets]), self._bias_column(n, x)], 1)
        zero = x.new_zeros(n, 1)
        d1, d2 = [], []
        for a in range(self.spatial_dims):
            d1.append(torch.cat([self._head_blocks([j.d1[a] for j in jets]), zero], 1))
            d2.append(torch.cat([self._head_blocks([j.d2[a] for j in jets]), zero], 1))
        return Jet(value, torch.stack(d1), torch.stack(d2))

    def _time_branch_index(self, j: int) -> int:
        return len(self.embed_x) + j

    def time(self, t: Tensor) -> Tensor:
        n_x = len(self.embed_x)
        branches = [self._mlp(self._time_branch_index(j))(e(t)) for j, e in enumerate(self.embed_t)]
        cols = torch.cat(branches, 1).repeat(1, n_x)  # matches A's (i, j, c) column order
        return torch.cat([cols, torch.ones(t.shape[0], 1, dtype=t.dtype)], 1)

    def time_jet(self, t: Tensor) -> Jet:
        seed = Jet.seed(t)
        n_x = len(self.embed_x)
        jets = [
            self._mlp(self._time_branch_index(j)).jet(_embedding(e).jet(seed))
            for j, e in enumerate(self.embed_t)
        ]
        m = t.shape[0]
        # Column order as in A: (spatial branch, temporal branch, unit), then the bias column.
        columns = torch.cat([j.value for j in jets], 1).repeat(1, n_x)
        value = torch.cat([columns, t.new_ones(m, 1)], 1)
        zero = t.new_zeros(1, m, 1)
        d1 = torch.cat([torch.cat([j.d1 for j in jets], 2).repeat(1, 1, n_x), zero], 2)
        d2 = torch.cat([torch.cat([j.d2 for j in jets], 2).repeat(1, 1, n_x), zero], 2)
        return Jet(value, d1, d2)


ARCHITECTURES: dict[str, type[SeparableCore]] = {"spinn": SeparablePINN, "stmsffn": STMsFFN}


def build_core(arch: ArchConfig, spatial_dims: int, seed: int = 0) -> SeparableCore:
    """The network an architecture describes, for a problem's dimensions, seeded."""
    if isinstance(arch, SpinnConfig):
        return SeparablePINN(spatial_dims, arch, seed)
    return STMsFFN(spatial_dims, arch, seed)


def core_from_config(config: dict[str, Any]) -> SeparableCore:
    """Rebuild a network from ``config()`` output (its ``name`` picks the architecture)."""
    return build_core(arch_from_dict(config), int(config["spatial_dims"]), int(config["seed"]))
