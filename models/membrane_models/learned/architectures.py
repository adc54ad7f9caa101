"""Typed network configurations: what a recipe names, a checkpoint stores, a manifest shows.

Each architecture is a frozen dataclass that ``networks.build_core`` turns into a network; the
spatial dimensions and the seed are not part of it (the problem and the run supply them).
``to_dict`` gives the plain data written to checkpoints (``weights_only`` loadable) and, with
``spatial_dims`` and ``seed`` added by the network, to manifests; ``arch_from_dict`` reads either
back. The plain form is the one earlier checkpoints hold, key for key, so they still load and
resume. No torch here: a configuration is data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, ClassVar

from membrane_errors import UserError

__all__ = [
    "ArchConfig",
    "FourierSpec",
    "GaussianFeatures",
    "HarmonicFeatures",
    "InvalidArchitecture",
    "SpinnConfig",
    "StmsffnConfig",
    "arch_from_dict",
    "features_from_dict",
]


class InvalidArchitecture(UserError):
    """An architecture configuration that cannot be built."""


def _check_count(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InvalidArchitecture(f"{name} must be an integer >= 1, got {value!r}")


def _check_number(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise InvalidArchitecture(f"{name} must be a finite number, got {value!r}")


@dataclass(frozen=True)
class HarmonicFeatures:
    """Fixed features [s, a_k cos(k pi s), a_k sin(k pi s)], k = 1..features, a_k = k^-decay.

    Decaying weights start the network smooth, so that its high harmonics are learned rather
    than inherited from the random initialisation.
    """

    kind: ClassVar[str] = "harmonic"

    features: int
    decay: float = 0.0
    include_input: bool = True

    def __post_init__(self) -> None:
        _check_count("features", self.features)
        _check_number("decay", self.decay)

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "kind": self.kind,
            "features": self.features,
            "include_input": self.include_input,
        }
        if self.decay:  # only when set, as the recipes always wrote it
            data["decay"] = self.decay
        return data


@dataclass(frozen=True)
class GaussianFeatures:
    """Fixed features [s, cos(s B), sin(s B)], B ~ N(0, sigma^2) drawn once from the seed."""

    kind: ClassVar[str] = "gaussian"

    features: int
    sigma: float
    include_input: bool = True

    def __post_init__(self) -> None:
        _check_count("features", self.features)
        _check_number("sigma", self.sigma)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "features": self.features,
            "sigma": self.sigma,
            "include_input": self.include_input,
        }


FourierSpec = HarmonicFeatures | GaussianFeatures


@dataclass(frozen=True)
class SpinnConfig:
    """``networks.SeparablePINN``: one tanh MLP per axis (SPINN, Cho et al. 2023).

    Attributes:
        rank: Number of separable terms r.
        width: Hidden width of every axis network.
        depth: Number of hidden layers of every axis network.
        space_features: Embedding of each space axis (None: the raw coordinate).
        time_features: Embedding of the time axis (None: the raw coordinate).
        skip: A linear path from each axis's embedding to its output (``networks.AxisNetwork``).
    """

    name: ClassVar[str] = "spinn"

    rank: int
    width: int = 64
    depth: int = 3
    space_features: FourierSpec | None = None
    time_features: FourierSpec | None = None
    skip: bool = False

    def __post_init__(self) -> None:
        for name in ("rank", "width", "depth"):
            _check_count(name, getattr(self, name))

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "name": self.name,
            "rank": self.rank,
            "width": self.width,
            "depth": self.depth,
            "space_features": _features_dict(self.space_features),
            "time_features": _features_dict(self.time_features),
        }
        if self.skip:  # only when set, so that earlier checkpoints' configs stay equal
            data["skip"] = True
        return data


@dataclass(frozen=True)
class StmsffnConfig:
    """``networks.STMsFFN``: the published multi-scale Fourier feature network.

    Attributes:
        width: Embedding and hidden width (even: cos and sin halves).
        hidden: Hidden layers, the embedding counted (as published: [d+1] + [width]*hidden + [1]).
        sigmas_x: Standard deviation of each spatial embedding's frequencies.
        sigmas_t: Standard deviation of each temporal embedding's frequencies.
        shared: One MLP for every branch (as published) instead of one per branch.
    """

    name: ClassVar[str] = "stmsffn"

    width: int = 100
    hidden: int = 3
    sigmas_x: tuple[float, ...] = (1.0,)
    sigmas_t: tuple[float, ...] = (1.0, 50.0)
    shared: bool = True

    def __post_init__(self) -> None:
        _check_count("width", self.width)
        _check_count("hidden", self.hidden)
        if self.width % 2:
            raise InvalidArchitecture(
                f"STMsFFN width must be even (cos and sin halves), got {self.width}"
            )
        # Lists from plain data become tuples: the config stays hashable and compares equal.
        object.__setattr__(self, "sigmas_x", tuple(float(s) for s in self.sigmas_x))
        object.__setattr__(self, "sigmas_t", tuple(float(s) for s in self.sigmas_t))
        if not self.sigmas_x or not self.sigmas_t:
            raise InvalidArchitecture("STMsFFN needs at least one sigma per axis group")

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "width": self.width,
            "hidden": self.hidden,
            "sigmas_x": list(self.sigmas_x),
            "sigmas_t": list(self.sigmas_t),
            "shared": self.shared,
        }


ArchConfig = SpinnConfig | StmsffnConfig

_ARCHITECTURES: dict[str, type[SpinnConfig] | type[StmsffnConfig]] = {
    SpinnConfig.name: SpinnConfig,
    StmsffnConfig.name: StmsffnConfig,
}
_FEATURES: dict[str, type[HarmonicFeatures] | type[GaussianFeatures]] = {
    HarmonicFeatures.kind: HarmonicFeatures,
    GaussianFeatures.kind: GaussianFeatures,
}
# What a network's own config() adds: the run supplies them, the architecture does not hold them.
_RUN_KEYS = ("spatial_dims", "seed")


def _features_dict(spec: FourierSpec | None) -> dict[str, Any] | None:
    return spec.to_dict() if spec is not None else None


def features_from_dict(data: dict[str, Any] | None) -> FourierSpec | None:
    """A feature embedding from its plain form (None stays None)."""
    if data is None:
        return None
    params = dict(data)
    kind = params.pop("kind", None)
    cls = _FEATURES.get(str(kind))
    if cls is None:
        known = ", ".join(sorted(_FEATURES))
        raise InvalidArchitecture(f"unknown Fourier feature kind {kind!r}; known: {known}")
    return cls(**_known_fields({f.name for f in fields(cls)}, params, f"{kind} features"))


def arch_from_dict(data: dict[str, Any]) -> ArchConfig:
    """An architecture from its plain form (a checkpoint's, or a network's ``config()``)."""
    params = {k: v for k, v in data.items() if k not in _RUN_KEYS}
    name = params.pop("name", None)
    cls = _ARCHITECTURES.get(str(name))
    if cls is None:
        known = ", ".join(sorted(_ARCHITECTURES))
        raise InvalidArchitecture(f"unknown architecture {name!r}; known: {known}")
    if cls is SpinnConfig:
        for key in ("space_features", "time_features"):
            if key in params:
                params[key] = features_from_dict(params[key])
    return cls(**_known_fields({f.name for f in fields(cls)}, params, f"architecture {name}"))


def _known_fields(known: set[str], params: dict[str, Any], what: str) -> dict[str, Any]:
    unknown = sorted(set(params) - known)
    if unknown:
        raise InvalidArchitecture(f"{what} has no field {', '.join(map(repr, unknown))}")
    return params
