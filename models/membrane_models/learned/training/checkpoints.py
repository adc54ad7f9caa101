"""Checkpoints: ``torch.save`` of tensors and plain data only, loadable with ``weights_only``.

A checkpoint holds the configuration's plain form, the weights, the optimisers' and random
generators' states, the loss history, the wall time and the command line: enough to resume a run
bit for bit (the Adam phase) and to export it with its provenance.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from membrane_errors import UserError
from membrane_models.learned.training.config import TrainConfig, build_model
from membrane_models.learned.transforms import PhysicalModel

__all__ = ["CHECKPOINT_FORMAT", "load_checkpoint", "model_from_checkpoint", "write_checkpoint"]

CHECKPOINT_FORMAT = 1


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a checkpoint (tensors and plain data only)."""
    if not path.is_file():
        raise UserError(f"no checkpoint at {path}")
    try:
        data: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a file that is not a checkpoint
        raise UserError(f"{path} is not a readable checkpoint: {exc}") from None
    if data.get("format") != CHECKPOINT_FORMAT:
        raise UserError(f"{path}: checkpoint format {data.get('format')!r} unsupported")
    return data


def model_from_checkpoint(data: dict[str, Any]) -> tuple[PhysicalModel, TrainConfig]:
    """Rebuild the trained model (in its training dtype) and its configuration."""
    config = TrainConfig.from_dict(data["config"])
    model = build_model(config)
    model.load_state_dict(data["model"])
    return model, config


def write_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write ``state`` (with the format number) through a temporary file."""
    tmp = path.with_suffix(".tmp")
    torch.save({"format": CHECKPOINT_FORMAT, **state}, tmp)
    tmp.replace(path)  # never leave a half-written checkpoint behind
