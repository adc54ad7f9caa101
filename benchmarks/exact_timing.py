"""Timings of the exact solutions: a full grid, and one frame on a fixed lattice.

For each forced problem at the default tolerance (1e-10):

- grid: build the series and evaluate it on the grid (41x41x101 membrane, 101x101 string);
  for the membrane against the baseline of the same values computed point by point
  (``at_points`` on the flattened grid, without the separable tensor products);
- frame: ``on_points(lattice)`` then ``frame(t)`` per call (20x20 membrane, 100-point string),
  against the baseline ``at_points(lattice, [t])`` per call (no precomputed mode shapes).

Prints a markdown table; ratios are baseline / fast path, measured in the same run.

    python benchmarks/exact_timing.py [--repeats 5] [--calls 2000]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from membrane_models.exact import exact_solution
from membrane_models.problems import make_problem

GRIDS = {"membrane-forced": (41, 41, 101), "string-forced": (101, 101)}
LATTICES = {"membrane-forced": 20, "string-forced": 100}


def _median_seconds(job: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        job()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def _lattice(name: str) -> np.ndarray:
    n = LATTICES[name]
    axis = np.linspace(0.0, 1.0, n)
    if name.startswith("membrane"):
        return np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
    return axis[:, None]


def _per_call_us(call: Callable[[float], object], times: np.ndarray) -> tuple[float, float]:
    samples = []
    for t in times:
        started = time.perf_counter()
        call(float(t))
        samples.append(time.perf_counter() - started)
    micro = np.array(samples) * 1e6
    return float(np.percentile(micro, 50)), float(np.percentile(micro, 99))


def report(name: str, repeats: int, calls: int) -> list[str]:
    """The two table rows of one problem."""
    sizes = GRIDS[name]
    problem = make_problem(name)
    axes = [np.linspace(0.0, 1.0, n) for n in sizes[:-1]]
    t = np.linspace(0.0, problem.t_end, sizes[-1])
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))

    fast = _median_seconds(lambda: exact_solution(problem).grid(*axes, t), repeats)
    solution = exact_solution(problem)
    shape = "x".join(map(str, sizes))
    if len(axes) == 1:  # the string's grid is at_points already: no separate baseline
        baseline, ratio = "-", "-"
    else:
        slow = _median_seconds(lambda: solution.at_points(points, t), repeats)
        build = _median_seconds(lambda: exact_solution(problem), repeats)
        baseline = f"{build + slow:.3f} s (build + at_points)"
        ratio = f"{(build + slow) / fast:.1f}"
    rows = [
        f"| {name} | build + grid {shape} ({solution.n_modes} modes) | {fast:.3f} s | "
        f"{baseline} | {ratio} |"
    ]
    lattice = _lattice(name)
    frame = solution.on_points(lattice)
    times = np.random.default_rng(0).uniform(0.0, problem.t_end * 1.2, calls)
    for warm in times[:50]:
        frame(float(warm))
    f50, f99 = _per_call_us(frame, times)
    b50, b99 = _per_call_us(lambda s: solution.at_points(lattice, [s]), times[: calls // 4])
    rows.append(
        f"| {name} | frame on {len(lattice)} points, p50 / p99 | {f50:.0f} / {f99:.0f} us | "
        f"{b50:.0f} / {b99:.0f} us (at_points per call) | {b50 / f50:.1f} (p50) |"
    )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--calls", type=int, default=2000)
    args = parser.parse_args()
    print("| problem | what | fast path | baseline | ratio |")
    print("| --- | --- | --- | --- | --- |")
    for name in GRIDS:
        for row in report(name, args.repeats, args.calls):
            print(row)


if __name__ == "__main__":
    main()
