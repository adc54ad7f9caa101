"""Training the Koopman latent model on the nonlinear string's training split.

The four losses of Gin et al. (2021), each relative per sample (the amplitudes span three
decades, and an absolute loss would ignore the small, linear ones):

The targets are the states' first ``pairs`` sine modes (the encoder reads the whole state):
no latent of size 2 pairs can carry more of the linear string, and against the whole state the
losses of the rough shapes (noise: 60% of it above mode 10) would be mostly what no model of
that size can reduce, their gradients pulling the smooth shapes' fit apart.

- ``autoencoder``: decode(encode(x_k)) against x_k;
- ``inner``: the inner autoencoder, inner_decode(inner_encode(v)) against v (v the outer
  encoder's output), which keeps v near the latent's span;
- ``prediction``: decode(K^m encode(x_k)) against x_{k+m}, m drawn from 1 to the trajectory's
  length (log-uniform, so one-step and long horizons both weigh);
- ``linearity``: K^m encode(x_k) against encode(x_{k+m});
- ``energy`` (a consistency loss of ours): the decoded energy at two random phases of the
  latent pairs, against each other. The string conserves its energy, and the latent radii
  are conserved exactly, but a nonlinear decoder can still make the energy depend on the
  phases; over 10^5 steps the phases visit combinations no 200-step trajectory showed, and
  without this term the decoded energy wandered from 0.1 to 1.3 of the reference's.

K^m turns each pair by m theta_j at once (the radii, hence the angles, are constant along a
rotation), so a horizon of 200 steps costs what one does. Only ``train.npz`` is read for the
gradients; ``validation.npz`` is what the progress line reports. Checkpoints hold the weights,
Adam's state, both random generators and the history, so ``--resume`` continues bit for bit.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from membrane_errors import UserError
from membrane_models.learned.koopman_network import KoopmanConfig, KoopmanNetwork

__all__ = [
    "KOOPMAN_CHECKPOINT_FORMAT",
    "KoopmanRun",
    "KoopmanTrainConfig",
    "load_koopman_checkpoint",
    "train_koopman",
]

logger = logging.getLogger(__name__)

KOOPMAN_CHECKPOINT_FORMAT = 1
_LOSSES = ("autoencoder", "inner", "prediction", "linearity", "energy")


@dataclass(frozen=True)
class KoopmanTrainConfig:
    """Everything that determines a run (with the seed and the data, its weights)."""

    network: KoopmanConfig = field(default_factory=KoopmanConfig)
    iterations: int = 50000
    batch: int = 128
    lr: float = 1e-3
    lr_final: float = 2e-5
    weights: tuple[float, ...] = (1.0, 0.1, 1.0, 0.1, 1.0)
    seed: int = 0
    checkpoint_every: int = 500
    validate_every: int = 500

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["weights"] = list(self.weights)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> KoopmanTrainConfig:
        values = dict(data)
        values["network"] = KoopmanConfig(**values["network"])
        values["weights"] = tuple(values["weights"])
        return cls(**values)


@dataclass
class KoopmanRun:
    """What a run ended with."""

    model: KoopmanNetwork
    config: KoopmanTrainConfig
    iterations: int
    wall_time: float
    history: list[dict[str, float]]
    checkpoint: Path | None


def _states(path: Path) -> tuple[Tensor, dict[str, Any]]:
    """(trajectories, snapshots, 2 points) float32 states of a split, and its parameters."""
    import json

    if not path.is_file():
        raise UserError(
            f"no dataset split at {path} (make one with `membrane data koopman-string`)"
        )
    with np.load(path, allow_pickle=False) as data:
        states = np.concatenate([data["u"], data["u_t"]], axis=2)
        parameters = json.loads(str(data["parameters"]))
    return torch.from_numpy(states.astype(np.float32)), parameters


def network_config_for(data_dir: Path, variant: str, pairs: int) -> KoopmanConfig:
    """The network's physics (points, dt, c, k) as the dataset's parameters record them."""
    _, parameters = _states(data_dir / "train.npz")
    return KoopmanConfig(
        points=int(parameters["points"]),
        pairs=pairs,
        variant=variant,
        dt=float(parameters["dt"]),
        c=float(parameters["c"]),
        k=float(parameters["k"]),
    )


def _relative(pred: Tensor, target: Tensor, whole: Tensor | None = None) -> Tensor:
    """Mean squared error relative to each target's square, per sample.

    ``whole`` (the untruncated state) floors the denominator at 1e-6 of its square: a shape
    with nothing in the kept modes (sin 9 pi x, say, with 8 pairs) would divide by zero.
    """
    num = torch.sum((pred - target) ** 2, dim=1)
    den = torch.sum(target**2, dim=1)
    if whole is not None:
        den = torch.maximum(den, 1e-6 * torch.sum(whole**2, dim=1))
    return torch.mean(num / (den + 1e-12))


def loss_terms(
    model: KoopmanNetwork, states: Tensor, generator: torch.Generator, batch: int
) -> dict[str, Tensor]:
    """The four losses on ``batch`` (trajectory, start, horizon) draws from ``states``."""
    trajectories, snapshots, _ = states.shape
    last = snapshots - 1
    which = torch.randint(trajectories, (batch,), generator=generator)
    log_m = torch.rand(batch, generator=generator) * math.log(last)
    horizon = torch.clamp(torch.exp(log_m).round().long(), 1, last)
    start = (torch.rand(batch, generator=generator) * (last - horizon + 1)).long()
    now = states[which, start] / model.unit
    later = states[which, start + horizon] / model.unit
    v = model.outer_encoder(now)
    z = model.inner_encoder(v)
    z_later = model.encode(later * model.unit)
    ahead = model.advance(z, horizon[:, None].to(z.dtype))
    phases = torch.rand((2 * batch, model.config.pairs), generator=generator) * (2 * math.pi)
    turned = model.turn(torch.cat([z, z]), phases)
    decoded = model.outer_decoder(model.inner_decoder(torch.cat([z, ahead, turned])))
    first, second = model.energy(decoded[2 * batch : 3 * batch]), model.energy(decoded[3 * batch :])
    return {
        "autoencoder": _relative(decoded[:batch], model.truncate(now), now),
        "inner": _relative(model.inner_decoder(z), v),
        "prediction": _relative(decoded[batch : 2 * batch], model.truncate(later), later),
        "linearity": _relative(ahead, z_later),
        "energy": torch.mean((first - second) ** 2 / (first**2 + second**2 + 1e-30)),
    }


def validation_error(model: KoopmanNetwork, states: Tensor, steps: int = 100) -> float:
    """Mean relative error of u after ``steps`` steps from each trajectory's first snapshots."""
    n = model.config.points
    starts = states[:, 0]
    with torch.no_grad():
        pred = model.decode(model.advance(model.encode(starts), float(steps)))[:, :n]
    want = states[:, steps, :n]
    scale = torch.sqrt(torch.mean(torch.sum(states[:, :, :n] ** 2, dim=2), dim=1))
    return float(torch.mean(torch.linalg.norm(pred - want, dim=1) / scale))


def _lr(config: KoopmanTrainConfig, iteration: int) -> float:
    fraction = iteration / max(config.iterations - 1, 1)
    return config.lr * (config.lr_final / config.lr) ** fraction


def load_koopman_checkpoint(path: Path) -> dict[str, Any]:
    """Read a Koopman checkpoint (tensors and plain data only)."""
    if not path.is_file():
        raise UserError(f"no checkpoint at {path}")
    data: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=True)
    if data.get("koopman_format") != KOOPMAN_CHECKPOINT_FORMAT:
        raise UserError(f"{path} is not a Koopman checkpoint")
    return data


def model_from_koopman_checkpoint(data: dict[str, Any]) -> KoopmanNetwork:
    """The trained network of a checkpoint."""
    config = KoopmanTrainConfig.from_dict(data["config"])
    model = KoopmanNetwork(config.network)
    model.load_state_dict(data["model"])
    return model.eval()


def train_koopman(
    config: KoopmanTrainConfig,
    data_dir: Path,
    out_dir: Path | None = None,
    command: str = "",
    resume: bool = False,
    progress: bool = True,
    until: int | None = None,
) -> KoopmanRun:
    """Train on ``data_dir/train.npz``; checkpoints go to ``out_dir/checkpoint.pt``.

    Args:
        config: The run's configuration.
        data_dir: A `membrane data koopman-string` output folder.
        out_dir: Where the checkpoint goes (None: nothing on disk).
        command: The command line (stored in the checkpoint and the manifest).
        resume: Continue ``out_dir/checkpoint.pt`` (same configuration).
        progress: A tqdm bar with the loss terms.
        until: Stop after this iteration (a checkpoint is written; ``resume`` continues).
    """
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed + 1)
    train_states, parameters = _states(data_dir / "train.npz")
    validation = data_dir / "validation.npz"
    val_states = _states(validation)[0] if validation.is_file() else None
    model = KoopmanNetwork(config.network)
    adam = torch.optim.Adam(model.parameters(), lr=config.lr)
    start, wall, history = 0, 0.0, []
    checkpoint = out_dir / "checkpoint.pt" if out_dir is not None else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    if resume:
        if checkpoint is None:
            raise UserError("resume needs an output directory")
        data = load_koopman_checkpoint(checkpoint)
        if data["config"] != config.to_dict():
            raise UserError(f"{checkpoint} was trained with another configuration")
        model.load_state_dict(data["model"])
        adam.load_state_dict(data["adam"])
        torch.set_rng_state(data["torch_rng"])
        generator.set_state(data["sampler_rng"])
        start, wall, history = data["iteration"], data["wall_time"], list(data["history"])
        command = data.get("command", command)
        logger.info("resumed %s at iteration %d", checkpoint, start)

    def save(iteration: int) -> None:
        if checkpoint is None:
            return
        state = {
            "koopman_format": KOOPMAN_CHECKPOINT_FORMAT,
            "config": config.to_dict(),
            "model": model.state_dict(),
            "adam": adam.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "sampler_rng": generator.get_state(),
            "iteration": iteration,
            "wall_time": wall,
            "history": history,
            "command": command,
            "data": str(data_dir),
            "data_parameters": parameters,
        }
        tmp = checkpoint.with_suffix(".tmp")
        torch.save(state, tmp)
        tmp.replace(checkpoint)

    bar = _progress_bar(config.iterations, start, progress)
    done = start
    try:
        for iteration in range(start, config.iterations):
            if until is not None and iteration >= until:
                break
            began = time.perf_counter()
            for group in adam.param_groups:
                group["lr"] = _lr(config, iteration)
            adam.zero_grad(set_to_none=True)
            terms = loss_terms(model, train_states, generator, config.batch)
            loss = sum(
                (w * terms[n] for w, n in zip(config.weights, _LOSSES, strict=True)),
                torch.zeros(()),
            )
            loss.backward()
            adam.step()
            wall += time.perf_counter() - began
            done = iteration + 1
            record = {"iteration": float(done), "wall_time": wall}
            record.update({k: float(v.detach()) for k, v in terms.items()})
            if val_states is not None and done % config.validate_every == 0:
                record["validation_100"] = validation_error(model, val_states)
                logger.info("iteration %d: %s", done, _fmt(record))
            history.append(record)
            if bar is not None:
                bar.update(1)
                shown = {k: f"{v:.2e}" for k, v in record.items() if k not in ("iteration",)}
                bar.set_postfix(shown, refresh=False)
            if done % config.checkpoint_every == 0:
                save(done)
            if not math.isfinite(float(loss.detach())):
                raise FloatingPointError(f"loss became {float(loss.detach())} at iteration {done}")
    finally:
        if bar is not None:
            bar.close()
    save(done)
    return KoopmanRun(model.eval(), config, done, wall, history, checkpoint)


def _fmt(record: dict[str, float]) -> str:
    return " ".join(f"{k}={v:.4g}" for k, v in record.items() if k != "iteration")


def _progress_bar(total: int, start: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=start, desc="train koopman", unit="it", dynamic_ncols=True)
