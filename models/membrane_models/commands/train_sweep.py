"""`membrane train --seeds ... / --sweep NAME=V1,V2,...`: many trainings of one problem, each in
OUT/<run>/, on an executor (``membrane_models.executors``: serial here, or Ray tasks).

Each run is ``train_run`` of a plain spec (picklable: it crosses to a Ray worker), which seeds
the run and pins torch to one thread itself, so a run's losses do not depend on where it ran;
OUT/sweep.json lists every run's final loss terms, in the runs' order.
"""

from __future__ import annotations

import itertools
import json
import logging
import time
from pathlib import Path
from typing import Any

from membrane_cli.arguments import UsageError
from membrane_models.executors import Executor, Job

__all__ = ["parse_seeds", "parse_sweep", "run_sweep", "sweep_specs", "train_run"]


def parse_seeds(text: str | None) -> list[int] | None:
    """``--seeds 0,1,2`` (or ``0-3``, 0 to 3 inclusive)."""
    if text is None:
        return None
    try:
        if "-" in text and "," not in text:
            low, high = (int(v) for v in text.split("-", 1))
            seeds = list(range(low, high + 1))
        else:
            seeds = [int(v) for v in text.split(",")]
    except ValueError:
        raise UsageError(f"--seeds takes integers, e.g. 0,1,2 or 0-3, got {text!r}") from None
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise UsageError(f"--seeds must name distinct seeds >= 0, got {text!r}")
    return seeds


def parse_sweep(items: list[str]) -> list[tuple[str, list[str]]]:
    """``--sweep c=5,8 --sweep k=0,100``: each parameter and its values (their product runs)."""
    sweeps = []
    for item in items:
        name, sep, values = item.partition("=")
        listed = [v for v in values.split(",") if v]
        if not sep or not name or not listed:
            raise UsageError(f"--sweep takes NAME=V1,V2,..., got {item!r}")
        sweeps.append((name, listed))
    return sweeps


def sweep_specs(
    base: dict[str, Any], seeds: list[int], sweeps: list[tuple[str, list[str]]]
) -> list[dict[str, Any]]:
    """One spec per run: every seed for every combination of the swept values."""
    specs = []
    names = [name for name, _ in sweeps]
    for values in itertools.product(*(listed for _, listed in sweeps)):
        for seed in seeds:
            sets = [*base["sets"], *(f"{n}={v}" for n, v in zip(names, values, strict=True))]
            label = ",".join(
                [*(f"{n}={v}" for n, v in zip(names, values, strict=True)), f"seed-{seed}"]
            )
            specs.append({**base, "seed": seed, "sets": sets, "name": label,
                          "out": str(Path(base["out"]) / label)})  # fmt: skip
    return specs


def train_run(spec: dict[str, Any]) -> dict[str, Any]:
    """One training of a sweep (in whichever process runs it): its final loss terms."""
    import torch

    from membrane_models.commands.exact import parse_assignments
    from membrane_models.learned.training import recipe, train

    torch.set_num_threads(1)  # as a single run; and two runs on two cores do not share threads
    changes: dict[str, Any] = {"seed": spec["seed"], "overrides": parse_assignments(spec["sets"])}
    for key in ("iterations", "lbfgs_fraction"):
        if spec.get(key) is not None:
            changes[key] = spec[key]
    config = recipe(spec["problem"], spec["arch"], **changes)
    out = Path(spec["out"])
    out.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(out / "train.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    train_logger = logging.getLogger("membrane_models")
    train_logger.addHandler(handler)
    train_logger.setLevel(logging.INFO)
    try:
        result = train(config, out_dir=out, command=spec["command"], progress=False)
    finally:
        train_logger.removeHandler(handler)
        handler.close()
    last = result.history[-1] if result.history else {}
    final = {k: v for k, v in last.items() if k not in ("iteration", "wall_time")}
    return {"name": spec["name"], "seed": spec["seed"], "sets": spec["sets"],
            "iterations": result.iterations, "wall_time": result.wall_time, "final": final,
            "checkpoint": str(result.checkpoint)}  # fmt: skip


def run_sweep(specs: list[dict[str, Any]], out: Path, executor: Executor, progress: bool) -> int:
    """Every run on ``executor``; OUT/sweep.json and a line per run."""
    from membrane_models.learned.training import build_model, recipe

    for spec in specs:  # every run's problem and overrides checked before any starts
        build_model(recipe(spec["problem"], spec["arch"], seed=spec["seed"],
                           overrides=_overrides(spec["sets"])))  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    jobs = [Job(spec["name"], train_run, (spec,)) for spec in specs]
    runs = executor.run(jobs, progress=progress)
    wall = time.perf_counter() - started
    summary = {"executor": executor.name, "wall_time": wall, "runs": runs}
    (out / "sweep.json").write_text(json.dumps(summary, indent=2) + "\n")
    for run in runs:
        terms = " ".join(f"{k}={v:.6e}" for k, v in run["final"].items())
        print(f"{run['name']}: {run['iterations']} iterations in {run['wall_time']:.1f} s: {terms}")
    print(f"{len(runs)} runs in {wall:.1f} s on {executor.name}: {out / 'sweep.json'}")
    return 0


def _overrides(sets: list[str]) -> dict[str, Any]:
    from membrane_models.commands.exact import parse_assignments

    return parse_assignments(sets)
