"""A training run's configuration, and the fresh model it describes.

``TrainConfig`` holds everything that determines a run (with the seed, the run is
deterministic). Its plain form (``to_dict``) is what a checkpoint stores and what ``--resume``
compares; ``from_dict`` reads it back, architecture included.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import torch

from membrane_errors import UserError
from membrane_models.learned.architectures import ArchConfig, arch_from_dict
from membrane_models.learned.networks import build_core
from membrane_models.learned.transforms import PhysicalModel, characteristic_amplitude
from membrane_models.problems import make_problem

__all__ = ["TrainConfig", "build_model"]


@dataclass
class TrainConfig:
    """Everything that determines a training run (with the seed, the run is deterministic).

    Attributes:
        problem: Registry name of the problem.
        arch: The network (``architectures.SpinnConfig`` or ``StmsffnConfig``); its seed is
            ``seed`` and its dimensions the problem's.
        overrides: Problem parameter overrides, NAME -> value as typed.
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
            (0: off; grid sampling only). See ``losses.modal_term``.
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
    arch: ArchConfig
    overrides: dict[str, str] = field(default_factory=dict)
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

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the architecture as its dict), as checkpoints store it."""
        plain = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {**plain, "arch": self.arch.to_dict(), "overrides": dict(self.overrides)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """The configuration ``to_dict`` wrote (a checkpoint's)."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown or "problem" not in data or "arch" not in data:
            raise UserError(f"not a training configuration (fields {sorted(data)})")
        return cls(**{**data, "arch": arch_from_dict(data["arch"])})


def build_model(config: TrainConfig) -> PhysicalModel:
    """A fresh, seeded model for a configuration."""
    problem = make_problem(config.problem, config.overrides)
    core = build_core(config.arch, problem.spatial_dims, config.seed)
    scale = characteristic_amplitude(problem) if config.output_scaling else 1.0
    model = PhysicalModel(core, problem, scale, hard_initial=config.hard_initial)
    return model.to(getattr(torch, config.dtype))
