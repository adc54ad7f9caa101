"""Figures for docs/MODELS.md (not a test): a sweep of short trainings one after another against
the same sweep on a local Ray of 2 workers, side by side in one run: wall time (Ray's start-up
included) and whether the final losses agree to the last digit.

    .venv/bin/python benchmarks/ray_sweep.py [--seeds 0-3] [--iterations 600] [--workers 2]

Each run is `membrane train string-forced --seeds ... --executor serial|ray` as a user runs it
(torch pinned to one thread in every training, as the command does).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MEMBRANE = str(Path(sys.executable).with_name("membrane"))


def _sweep(out: Path, seeds: str, iterations: int, *executor: str) -> tuple[float, dict]:
    command = [MEMBRANE, "train", "string-forced", "--out", str(out), "--seeds", seeds,
               "--iterations", str(iterations), "--no-progress", *executor]  # fmt: skip
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started, json.loads((out / "sweep.json").read_text())


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", default="0-3")
    parser.add_argument("--iterations", type=int, default=600)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        serial_s, serial = _sweep(root / "serial", args.seeds, args.iterations)
        ray_s, on_ray = _sweep(root / "ray", args.seeds, args.iterations,
                               "--executor", "ray", "--workers", str(args.workers))  # fmt: skip
    same = [r["final"] for r in serial["runs"]] == [r["final"] for r in on_ray["runs"]]
    print(json.dumps({
        "runs": len(serial["runs"]), "iterations": args.iterations, "workers": args.workers,
        "serial_wall_s": round(serial_s, 1), "ray_wall_s": round(ray_s, 1),
        "ratio": round(ray_s / serial_s, 3), "same_final_losses": same,
        "per_run_s": {"serial": [round(r["wall_time"], 1) for r in serial["runs"]],
                      "ray": [round(r["wall_time"], 1) for r in on_ray["runs"]]},
        "final": [r["final"] for r in on_ray["runs"]],
    }, indent=2))  # fmt: skip
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
