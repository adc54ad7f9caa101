"""The Koopman network against three physics baselines on the test split, for docs/KOOPMAN.md.

(a) the Koopman network (the zoo's ONNX graphs, onnxruntime), 10 latent pairs + 1 invariant;
(b) the linear modal model truncated to 10 modes (position and velocity: state size 20);
(c) exact linear stepping with every lattice mode (the live `ModalEngine`, 128 modes, no step
    limit): wrong for the nonlinear string by exactly the nonlinearity;
(d) the nonlinear Galerkin model truncated to 10 modes (DOP853 on the Kirchhoff-Carrier
    system of the first 10 sine modes: state size 20).

Errors: ``koopman_evaluate.error_table`` (relative to each trajectory's displacement scale, the
reference the test file's snapshots and the 128-mode Galerkin solver beyond them). Step costs:
one trajectory, in-process, microseconds per step with the frame (decode / synthesis) included.

    python benchmarks/koopman_comparison.py --data runs/koopman-data --out runs/koopman-compare
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from membrane_models.artifacts.koopman_evaluate import (
    HORIZONS,
    TestSplit,
    error_table,
    onnx_rollout,
)
from membrane_models.artifacts.koopman_manifest import KoopmanManifest, find_koopman_model
from membrane_models.exact.kirchhoff_carrier import solve_kirchhoff
from membrane_models.live import ModalEngine
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]
MODES = 10


def _projection(points: int, modes: int) -> tuple[FloatArray, FloatArray]:
    x = np.arange(1, points + 1) / (points + 1)
    sines = np.sin(np.pi * np.outer(x, np.arange(1, modes + 1)))  # (P, modes)
    return 2.0 / (points + 1) * sines, sines


def linear_modal(test: TestSplit, modes: int = MODES) -> Any:
    """(b): the first ``modes`` sine modes, each stepped exactly as a linear oscillator."""
    project, sines = _projection(test.points, modes)
    omega = np.pi * test.string.c * np.arange(1, modes + 1)

    def rollout(initial: FloatArray, steps: Sequence[int]) -> dict[int, FloatArray]:
        q, p = initial[:, : test.points] @ project, initial[:, test.points :] @ project
        out = {}
        for m in steps:
            wt = omega * m * test.dt
            out[m] = (q * np.cos(wt) + p / omega * np.sin(wt)) @ sines.T
        return out

    return rollout


def live_engine(test: TestSplit) -> Any:
    """(c): the live engine, every lattice mode, stepped one dt at a time."""
    engine = ModalEngine(
        make_problem("string-kirchhoff"),
        test.points + 2,
        test.dt,
        modes=test.points,
        step_limit=None,
    )

    def rollout(initial: FloatArray, steps: Sequence[int]) -> dict[int, FloatArray]:
        out: dict[int, list[FloatArray]] = {m: [] for m in steps}
        for state0 in initial:
            pad = np.zeros(test.points + 2)
            u, v = pad.copy(), pad.copy()
            u[1:-1], v[1:-1] = state0[: test.points], state0[test.points :]
            state = engine.start(u, v).state
            done = 0
            for m in sorted(steps):
                for _ in range(m - done):
                    state = engine.step(state, frame=False).state
                done = m
                out[m].append(engine.frame(state)[1:-1])
        return {m: np.asarray(rows) for m, rows in out.items()}

    return rollout, engine


def galerkin(test: TestSplit, modes: int = MODES) -> Any:
    """(d): the Kirchhoff-Carrier Galerkin system of the first ``modes`` modes (DOP853)."""
    project, sines = _projection(test.points, modes)

    def rollout(initial: FloatArray, steps: Sequence[int]) -> dict[int, FloatArray]:
        q0s, p0s = initial[:, : test.points] @ project, initial[:, test.points :] @ project
        times = np.asarray(sorted(steps), dtype=np.float64) * test.dt
        rows = [
            solve_kirchhoff(test.string, q, p, times).q @ sines.T
            for q, p in zip(q0s, p0s, strict=True)
        ]
        stacked = np.asarray(rows)  # (n, steps, P)
        return {m: stacked[:, i] for i, m in enumerate(sorted(steps))}

    return rollout


def step_costs(manifest: KoopmanManifest, test: TestSplit, engine: ModalEngine) -> dict[str, float]:
    """Microseconds per step (frame included), one trajectory, median of repeated runs."""
    from membrane_models.artifacts.evaluate import onnx_session

    state0 = test.states[:1, 0]
    encoder = onnx_session(manifest.verify("encoder"))
    stepper = onnx_session(manifest.verify("step"))
    decoder = onnx_session(manifest.verify("decoder"))
    z = encoder.run(None, {"state": state0.astype(np.float32)})[0]
    costs: dict[str, float] = {}

    def timed(fn: Any, n: int = 2000) -> float:
        samples = []
        for _ in range(n):
            began = time.perf_counter()
            fn()
            samples.append(time.perf_counter() - began)
        return float(np.median(samples) * 1e6)

    holder = {"z": z}

    def koopman() -> None:
        holder["z"] = stepper.run(None, {"z": holder["z"]})[0]
        decoder.run(None, {"z": holder["z"]})

    costs["a_koopman"] = timed(koopman)
    project, sines = _projection(test.points, MODES)
    omega = np.pi * np.arange(1, MODES + 1) * test.string.c
    c, s = np.cos(omega * test.dt), np.sin(omega * test.dt)
    qp = {"q": state0[0, : test.points] @ project, "p": state0[0, test.points :] @ project}

    def modal() -> None:
        q, p = qp["q"], qp["p"]
        qp["q"], qp["p"] = q * c + p / omega * s, p * c - q * omega * s
        _ = sines @ qp["q"]

    costs["b_linear_modal"] = timed(modal)
    pad = np.zeros(test.points + 2)
    pad[1:-1] = state0[0, : test.points]
    live = {"state": engine.start(pad).state}

    def step_live() -> None:
        live["state"] = engine.step(live["state"]).state

    costs["c_live_engine"] = timed(step_live)
    q0, p0 = qp["q"], qp["p"]
    times = np.arange(1, 201) * test.dt
    began = time.perf_counter()
    solution = solve_kirchhoff(test.string, q0, p0, times)
    _ = solution.q @ sines.T
    costs["d_galerkin"] = (time.perf_counter() - began) / times.size * 1e6
    return costs


def plot(tables: dict[str, dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("smooth", "strong"), ("rough", "strong"), ("smooth", "linear"), ("rough", "linear")]
    labels = {
        "a_koopman": "(a) Koopman network",
        "b_linear_modal": "(b) linear, 10 modes",
        "c_live_engine": "(c) linear, all modes (live engine)",
        "d_galerkin": "(d) nonlinear Galerkin, 10 modes",
    }
    figure, axes = plt.subplots(1, len(panels), figsize=(16, 4), sharey=True)
    for axis, (family, band) in zip(axes, panels, strict=True):
        for name, table in tables.items():
            row = next(
                (r for r in table["rows"] if (r["family"], r["band"]) == (family, band)), None
            )
            if row is None:
                continue
            steps = [int(s) for s in row["errors"]]
            axis.loglog(steps, list(row["errors"].values()), "o-", label=labels[name])
        axis.set_title(f"{family} shapes, {band} band")
        axis.set_xlabel("steps (dt = 0.01)")
        axis.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("relative error of u")
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--model", default="koopman-string")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    manifest = find_koopman_model(args.model)
    if manifest is None:
        raise SystemExit(f"no Koopman model {args.model!r}")
    test = TestSplit.read(args.data / "test.npz")
    live, engine = live_engine(test)
    rollouts = {
        "a_koopman": onnx_rollout(manifest),
        "b_linear_modal": linear_modal(test),
        "c_live_engine": live,
        "d_galerkin": galerkin(test),
    }
    tables = {}
    for name, rollout in rollouts.items():
        began = time.perf_counter()
        tables[name] = error_table(rollout, test, HORIZONS)
        print(f"{name}: {time.perf_counter() - began:.1f} s")
    costs = step_costs(manifest, test, engine)
    result = {"tables": tables, "step_us": costs, "modes": MODES}
    (args.out / "results.json").write_text(json.dumps(result, indent=2) + "\n")
    plot(tables, args.out / "comparison.png")
    _print(tables, costs)


def _print(tables: dict[str, dict[str, Any]], costs: dict[str, float]) -> None:
    names = list(tables)
    print("| family | band | n | steps | " + " | ".join(names) + " |")
    print("| --- " * (4 + len(names)) + "|")
    first = tables[names[0]]
    for index, row in enumerate(first["rows"]):
        for step in first["steps"]:
            cells = [tables[n]["rows"][index]["errors"][str(step)] for n in names]
            text = " | ".join(f"{v:.2e}" for v in cells)
            print(f"| {row['family']} | {row['band']} | {row['trajectories']} | {step} | {text} |")
    print("step cost (us): " + ", ".join(f"{k} {v:.1f}" for k, v in costs.items()))
    assert all(math.isfinite(v) for v in costs.values())


if __name__ == "__main__":
    main()
