"""The optimiser loop: Adam on resampled grids, then L-BFGS on a fixed one, with checkpoints.

One thread and a seed make a run deterministic; a run stopped at a checkpoint and resumed gives
the same Adam phase bit for bit (an L-BFGS phase restarts its curvature history and draws a
fresh grid).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from membrane_errors import UserError
from membrane_models.learned.training.checkpoints import load_checkpoint, write_checkpoint
from membrane_models.learned.training.collocation import Collocation, sample_collocation
from membrane_models.learned.training.config import TrainConfig, build_model
from membrane_models.learned.training.losses import loss_terms
from membrane_models.learned.transforms import PhysicalModel

__all__ = ["Monitor", "TrainResult", "WeightAverage", "train"]

logger = logging.getLogger(__name__)

Monitor = Callable[[PhysicalModel], dict[str, float]]


class WeightAverage:
    """A running mean of a model's weights (tensors only, so it checkpoints with the rest)."""

    def __init__(self) -> None:
        self.mean: dict[str, Tensor] = {}
        self.count = 0

    def add(self, model: PhysicalModel) -> None:
        self.count += 1
        for name, value in model.state_dict().items():
            if name not in self.mean:
                self.mean[name] = value.detach().clone()
            else:
                self.mean[name] += (value.detach() - self.mean[name]) / self.count

    def apply(self, model: PhysicalModel) -> None:
        """Load the mean into the model (nothing if nothing was added)."""
        if self.count:
            model.load_state_dict(self.mean)

    def state(self) -> dict[str, Any] | None:
        return {"mean": self.mean, "count": self.count} if self.count else None

    def restore(self, state: dict[str, Any] | None) -> None:
        if state:
            self.mean, self.count = dict(state["mean"]), int(state["count"])


@dataclass
class TrainResult:
    """What a run ended with."""

    model: PhysicalModel
    config: TrainConfig
    iterations: int
    wall_time: float
    history: list[dict[str, float]]
    checkpoint: Path | None


def _adam_lr(config: TrainConfig, step: int) -> float:
    if config.lr_final is None:  # the published inverse-time decay
        return config.lr / (1.0 + 0.9 * step / 2000.0)
    steps = max(config.adam_iterations - 1, 1)
    return config.lr * (config.lr_final / config.lr) ** (step / steps)


def train(
    config: TrainConfig,
    out_dir: Path | None = None,
    command: str = "",
    resume: bool = False,
    monitor: Monitor | None = None,
    progress: bool = True,
    time_budget: float | None = None,
    until: int | None = None,
) -> TrainResult:
    """Train a model; checkpoints go to ``out_dir/checkpoint.pt`` when ``out_dir`` is given.

    Args:
        config: The run's configuration.
        out_dir: Where the checkpoint goes (None: keep nothing on disk).
        command: The command line that started the run (stored in the checkpoint).
        resume: Continue from ``out_dir/checkpoint.pt`` (same configuration).
        monitor: Called every ``config.monitor_every`` iterations; returns figures to log.
        progress: Show a tqdm progress bar with the loss terms.
        time_budget: Stop after this many seconds of training (None: run all iterations).
        until: Stop after this iteration (a checkpoint is written; ``resume`` continues).
    """
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed + 1)
    model = build_model(config)
    problem = model.problem
    params = list(model.parameters())
    adam = torch.optim.Adam(params, lr=config.lr)
    lbfgs = torch.optim.LBFGS(
        params,
        lr=1.0,
        max_iter=1,
        max_eval=25,
        history_size=50,
        line_search_fn="strong_wolfe",
        tolerance_grad=0.0,
        tolerance_change=0.0,
    )
    start, wall, history = 0, 0.0, []
    average = WeightAverage()
    lbfgs_scale: float | None = None
    checkpoint = out_dir / "checkpoint.pt" if out_dir is not None else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    if resume:
        if checkpoint is None:
            raise UserError("resume needs an output directory")
        data = load_checkpoint(checkpoint)
        if data["config"] != config.to_dict():
            raise UserError(f"{checkpoint} was trained with another configuration")
        model.load_state_dict(data["model"])
        adam.load_state_dict(data["adam"])
        if data.get("lbfgs"):
            lbfgs.load_state_dict(data["lbfgs"])
        torch.set_rng_state(data["torch_rng"])
        generator.set_state(data["sampler_rng"])
        start, wall, history = data["iteration"], data["wall_time"], list(data["history"])
        lbfgs_scale = data.get("lbfgs_scale")
        average.restore(data.get("average"))
        command = data.get("command", command)
        logger.info("resumed %s at iteration %d", checkpoint, start)

    def save(iteration: int) -> None:
        if checkpoint is None:
            return
        write_checkpoint(
            checkpoint,
            {
                "config": config.to_dict(),
                "model": model.state_dict(),
                "transform": model.transform_config(),
                "problem": config.problem,
                "parameters": problem.parameters(),
                "iteration": iteration,
                "adam": adam.state_dict(),
                "lbfgs": lbfgs.state_dict() if iteration > config.adam_iterations else None,
                "lbfgs_scale": lbfgs_scale,
                "torch_rng": torch.get_rng_state(),
                "sampler_rng": generator.get_state(),
                "wall_time": wall,
                "command": command,
                "history": history,
                "average": average.state(),
            },
        )

    fine: Collocation | None = None
    bar = _progress_bar(config.iterations, start, progress)
    done = start
    try:
        for iteration in range(start, config.iterations):
            if time_budget is not None and wall >= time_budget:
                break
            if until is not None and iteration >= until:
                break
            began = time.perf_counter()
            if iteration < config.adam_iterations:
                terms = _adam_step(model, adam, config, generator, iteration)
            else:
                lbfgs_done = iteration - config.adam_iterations
                every = config.lbfgs_resample_every
                if fine is None or (every and lbfgs_done and lbfgs_done % every == 0):
                    fine = sample_collocation(problem, config, generator, fine=True)
                    lbfgs.state.clear()
                    lbfgs_scale = None
                if lbfgs_scale is None:
                    lbfgs_scale = 1.0 / max(_total_loss(model, fine, config, generator), 1e-300)
                terms = _lbfgs_step(model, lbfgs, fine, config, generator, lbfgs_scale)
            wall += time.perf_counter() - began
            done = iteration + 1
            record = {"iteration": float(done), "wall_time": wall, **terms}
            if monitor is not None and config.monitor_every and done % config.monitor_every == 0:
                record.update(monitor(model))
                logger.info("iteration %d: %s", done, _fmt(record))
            elif done % 200 == 0:
                logger.info("iteration %d: %s", done, _fmt(record))
            history.append(record)
            if bar is not None:
                bar.update(1)
                bar.set_postfix({k: f"{v:.2e}" for k, v in terms.items()}, refresh=False)
            if done > config.iterations - config.average_window:
                average.add(model)
            if done % config.checkpoint_every == 0:
                save(done)
            if not all(math.isfinite(v) for v in terms.values()):
                raise FloatingPointError(f"loss became {terms} at iteration {done}")
    finally:
        if bar is not None:
            bar.close()
    if done == config.iterations:
        average.apply(model)
    save(done)
    return TrainResult(model, config, done, wall, history, checkpoint)


def _total_loss(
    model: PhysicalModel, points: Collocation, config: TrainConfig, generator: torch.Generator
) -> float:
    state = generator.get_state()
    with torch.no_grad():
        loss = sum(float(v) for v in loss_terms(model, points, config, generator).values())
    generator.set_state(state)
    return loss


def _fmt(record: dict[str, float]) -> str:
    return " ".join(f"{k}={v:.4g}" for k, v in record.items() if k != "iteration")


def _progress_bar(total: int, start: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=start, desc="train", unit="it", dynamic_ncols=True)


def _adam_step(
    model: PhysicalModel,
    adam: torch.optim.Adam,
    config: TrainConfig,
    generator: torch.Generator,
    iteration: int,
) -> dict[str, float]:
    for group in adam.param_groups:
        group["lr"] = _adam_lr(config, iteration)
    points = sample_collocation(model.problem, config, generator)
    adam.zero_grad(set_to_none=True)
    terms = loss_terms(model, points, config, generator)
    loss = sum(terms.values(), torch.zeros(()))
    loss.backward()
    adam.step()
    return {k: float(v.detach()) for k, v in terms.items()}


def _lbfgs_step(
    model: PhysicalModel,
    lbfgs: torch.optim.LBFGS,
    points: Collocation,
    config: TrainConfig,
    generator: torch.Generator,
    loss_scale: float,
) -> dict[str, float]:
    """One L-BFGS iteration on the fixed grid; the objective is the loss times ``loss_scale``.

    The scale brings the objective to O(1): L-BFGS's curvature test (y.s > 1e-10) and its line
    search tolerances are absolute, and at losses near 1e-6 they stop every update.
    """
    # Soft initial terms draw their points inside loss_terms: fix them for L-BFGS's line search.
    state = generator.get_state()
    last: dict[str, float] = {}

    def closure() -> Tensor:
        generator.set_state(state)
        lbfgs.zero_grad(set_to_none=True)
        terms = loss_terms(model, points, config, generator)
        loss = sum(terms.values(), torch.zeros(())) * loss_scale
        loss.backward()
        last.update({k: float(v.detach()) for k, v in terms.items()})
        return loss

    before = [p.detach().clone() for p in model.parameters()]
    lbfgs.step(closure)
    if all(torch.equal(a, p) for a, p in zip(before, model.parameters(), strict=True)):
        # No step taken (its direction was no longer one of descent): restart from the
        # gradient with a fresh curvature history instead of stalling for good.
        logger.debug("L-BFGS stalled; history cleared")
        lbfgs.state.clear()
        lbfgs.step(closure)
    return last
