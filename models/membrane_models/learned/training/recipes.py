"""The shipped training recipes, and the published configuration they are measured against.

Each recipe was chosen by measurement; what was tried on the way, and why each setting is what
it is, is in docs/MODELS.md ("Why the recipes are what they are" and the table after it).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from membrane_errors import UserError
from membrane_models.learned.architectures import HarmonicFeatures, SpinnConfig, StmsffnConfig
from membrane_models.learned.training.config import TrainConfig

__all__ = ["PUBLISHED", "RECIPES", "recipe"]

# The plucks' network: wide in frequency for the travelling corners (mode n rings at time
# harmonic 2n), skip paths so that every harmonic is one weight from the output.
_PLUCKED_ARCH = SpinnConfig(
    rank=64,
    width=64,
    depth=3,
    space_features=HarmonicFeatures(32, decay=1.0),
    time_features=HarmonicFeatures(64, decay=1.0),
    skip=True,
)
# Both plucks: the modal term outweighs the pointwise residual, which a smooth network cannot
# make small at the corners.
_PLUCKED: dict[str, Any] = {
    "arch": _PLUCKED_ARCH,
    "iterations": 14000,
    "lbfgs_fraction": 0.85,
    "lbfgs_space_points": 256,
    "lbfgs_time_points": 256,
    "modal_weight": 1e6,
}

# name -> TrainConfig fields (with ``problem`` added by ``recipe``).
RECIPES: dict[str, dict[str, Any]] = {
    "string-forced": {
        "arch": SpinnConfig(
            rank=32,
            width=64,
            depth=3,
            space_features=HarmonicFeatures(16),
            time_features=HarmonicFeatures(8),
        ),
        "iterations": 12000,
        "lbfgs_fraction": 0.85,
        "lbfgs_space_points": 256,
        "lbfgs_time_points": 256,
        "modal_modes": 16,
        # The error is almost all in the low modes, which only the modal term sees.
        "modal_weight": 100.0,
    },
    # The kink's Dirac enters through its first 64 sine modes; the modal term projects on its
    # own uniform grid, so that one fixed L-BFGS grid serves (mode 64 rings at harmonic 128).
    "string-plucked": {
        **_PLUCKED,
        "arch": dataclasses.replace(
            _PLUCKED_ARCH,
            space_features=HarmonicFeatures(64, decay=1.0),
            time_features=HarmonicFeatures(128, decay=1.0),
        ),
        "modal_modes": 64,
        "kink_modes": 64,
        "modal_points": 256,
        "iterations": 12000,
        "lbfgs_fraction": 0.825,
        "lbfgs_resample_every": 0,
    },
    # One fixed L-BFGS grid: a redrawn one restarts L-BFGS's curvature history every time.
    "string-plucked-smooth": {
        **_PLUCKED,
        "modal_modes": 48,
        "modal_points": 256,
        "iterations": 16000,
        "lbfgs_fraction": 0.86875,
        "lbfgs_resample_every": 0,
    },
    # The modal term on its own grid, so that L-BFGS on one fixed grid cannot fit that grid.
    "membrane-forced": {
        "arch": SpinnConfig(
            rank=48,
            width=64,
            depth=3,
            space_features=HarmonicFeatures(12),
            time_features=HarmonicFeatures(12),
        ),
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
PUBLISHED: dict[str, StmsffnConfig] = {
    "string-forced": StmsffnConfig(sigmas_x=(1.0,), sigmas_t=(1.0, 50.0)),
    "membrane-forced": StmsffnConfig(sigmas_x=(1.0,), sigmas_t=(1.0, 10.0)),
}
_PUBLISHED_OTHER = StmsffnConfig(sigmas_x=(1.0,), sigmas_t=(1.0, 10.0))


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
    elif family == "stmsffn":
        base = {
            "problem": problem,
            "arch": PUBLISHED.get(problem, _PUBLISHED_OTHER),
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
