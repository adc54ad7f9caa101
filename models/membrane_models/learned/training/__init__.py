"""Physics-informed training (torch), one concept per module:

- ``config``: ``TrainConfig`` (everything that determines a run) and ``build_model``;
- ``recipes``: the shipped recipes and the published configuration (``recipe``);
- ``collocation``: where the residual is evaluated, and the force there;
- ``losses``: the residual, its modal term, soft initial conditions;
- ``loop``: Adam then L-BFGS, checkpoints on the way (``train``);
- ``checkpoints``: reading and writing them (tensors and plain data only).

The names below are the package's public surface; the modules hold the rest.
"""

from membrane_models.learned.training.checkpoints import (
    CHECKPOINT_FORMAT,
    load_checkpoint,
    model_from_checkpoint,
)
from membrane_models.learned.training.collocation import Collocation, sample_collocation
from membrane_models.learned.training.config import TrainConfig, build_model
from membrane_models.learned.training.loop import Monitor, TrainResult, WeightAverage, train
from membrane_models.learned.training.losses import loss_terms, modal_term
from membrane_models.learned.training.recipes import PUBLISHED, RECIPES, recipe

__all__ = [
    "CHECKPOINT_FORMAT",
    "PUBLISHED",
    "RECIPES",
    "Collocation",
    "Monitor",
    "TrainConfig",
    "TrainResult",
    "WeightAverage",
    "build_model",
    "load_checkpoint",
    "loss_terms",
    "modal_term",
    "model_from_checkpoint",
    "recipe",
    "sample_collocation",
    "train",
]
