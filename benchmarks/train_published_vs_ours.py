"""The published training configuration against ours, on the same wall-clock budget.

Published (seed-facts.md): STMsFFN [d+1]+[100]*3+[1] with its sigmas, Adam 1e-3 with
inverse-time decay (0.9 every 2000 steps), 1440 scattered collocation points resampled every
step, soft initial conditions (applied at t = 0), no output scaling, float32. Ours: the
shipped recipe (``membrane_models.learned.training.RECIPES``). Both train on this machine, one
after the other, each for at most ``--budget`` seconds of training time; the relative L2 error
against the exact solution on the standard grid is recorded every ``--every`` iterations (not
counted in the time).

Writes ``OUT/results.json``, ``OUT/table.md`` and ``OUT/curves.png``. Problems already in
``OUT/results.json`` from an earlier run are kept (a rerun replaces only the problems it trains),
so the problems can be run one at a time and still end in one table.

    python benchmarks/train_published_vs_ours.py --budget 900 --out runs/bench-train
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from membrane_models.artifacts.evaluate import reference_on_grid
from membrane_models.learned.training import TrainConfig, recipe, train
from membrane_models.learned.transforms import PhysicalModel
from membrane_models.problems import make_problem

logger = logging.getLogger("train_published_vs_ours")


def _monitor(config: TrainConfig) -> Any:
    points, exact = reference_on_grid(make_problem(config.problem, config.overrides))
    inputs = torch.from_numpy(points)

    def monitor(model: PhysicalModel) -> dict[str, float]:
        with torch.no_grad():
            dtype = next(model.parameters()).dtype
            u = model(inputs.to(dtype)).double().numpy()[:, 0]
        return {"rel_l2": float(np.linalg.norm(u - exact) / np.linalg.norm(exact))}

    return monitor


def run_one(config: TrainConfig, budget: float) -> list[tuple[float, float]]:
    """(training seconds, relative L2) pairs until the budget or the last iteration."""
    result = train(config, monitor=_monitor(config), time_budget=budget, progress=False)
    curve = [(h["wall_time"], h["rel_l2"]) for h in result.history if "rel_l2" in h]
    final = _monitor(config)(result.model)["rel_l2"]
    curve.append((result.wall_time, final))
    return curve


def _at(curve: list[tuple[float, float]], seconds: float) -> float:
    """The error reached by ``seconds`` of training (last record at or before it)."""
    before = [err for wall, err in curve if wall <= seconds]
    return before[-1] if before else float("nan")


def _cell(error: float) -> str:
    return "-" if np.isnan(error) else f"{error:.2e}"


def _table(results: dict[str, dict[str, list[tuple[float, float]]]], budget: float) -> str:
    marks = [budget / 4, budget / 2, budget]
    head = "| problem | training | " + " | ".join(f"L2 at {m:.0f} s" for m in marks) + " |"
    lines = [head, "|" + " --- |" * (2 + len(marks))]
    for problem, runs in results.items():
        for label, curve in runs.items():
            # "-": no error measured yet by then (the first record comes after --every steps).
            cells = " | ".join(_cell(_at(curve, m)) for m in marks)
            lines.append(f"| {problem} | {label} | {cells} |")
    return "\n".join(lines) + "\n"


def _plot(results: dict[str, dict[str, list[tuple[float, float]]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4), squeeze=False)
    for ax, (problem, runs) in zip(axes[0], results.items(), strict=True):
        for label, curve in runs.items():
            walls, errors = zip(*curve, strict=True)
            ax.semilogy(walls, errors, label=label)
        ax.set_title(problem)
        ax.set_xlabel("training time (s)")
        ax.set_ylabel("relative L2 error")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _earlier_results(path: Path, rerun: list[str]) -> dict[str, dict[str, list[Any]]]:
    """Results of problems that this run does not retrain, from an earlier run into ``OUT``."""
    if not path.is_file():
        return {}
    earlier: dict[str, dict[str, list[Any]]] = json.loads(path.read_text())
    return {problem: runs for problem, runs in earlier.items() if problem not in rerun}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--budget", type=float, default=900.0, help="seconds per run")
    parser.add_argument("--every", type=int, default=250, help="iterations between errors")
    parser.add_argument("--problems", nargs="+", default=["string-forced", "membrane-forced"])
    parser.add_argument("--out", type=Path, default=Path("runs/bench-train"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)  # on the shared 2-core machine a second thread only waits
    args.out.mkdir(parents=True, exist_ok=True)
    results = _earlier_results(args.out / "results.json", args.problems)
    for problem in args.problems:
        ours = recipe(problem, monitor_every=args.every)
        optimiser = "Adam + L-BFGS" if ours.lbfgs_iterations else "Adam"
        runs = {
            "published (STMsFFN, Adam)": recipe(problem, "stmsffn", monitor_every=args.every),
            f"ours (SPINN, {optimiser})": ours,
        }
        results[problem] = {}
        for label, config in runs.items():
            logger.info("%s: %s for up to %.0f s", problem, label, args.budget)
            results[problem][label] = run_one(config, args.budget)
            # Written after every run, so that a stopped benchmark keeps what it measured.
            (args.out / "results.json").write_text(json.dumps(results, indent=1))
    table = _table(results, args.budget)
    (args.out / "table.md").write_text(table)
    _plot(results, args.out / "curves.png")
    print(table)


if __name__ == "__main__":
    main()
