"""Cost of one live step, in-process, against a bare numpy baseline of the same size.

Each row steps a ``ModalEngine`` with one probe moving on a small circle (pressing 1e-5 deep,
r = 0.05) and times every call with ``perf_counter``: the step alone (the haptic loop, no frame)
and the step with its frame (the display loop). The baseline, timed in the same loop, one call
after each step so that background load weighs on both alike, is the bare product that turns
modal amplitudes into a frame of the same size: a dense (points x modes) matrix-vector product
where that matrix is small (20 x 20: 400 x 324), the separable T_x Q T_y^T where a dense one
would not fit (100 x 100 x 9604 modes would be 768 MB). Ratios are engine / baseline.

    OPENBLAS_NUM_THREADS=1 python benchmarks/live_step.py [--calls 20000]

Run it with BLAS pinned to one thread, as a latency server should be (docs/BENCHMARKS.md): on a
shared machine a threaded BLAS turns the 100 x 100 products' tail into milliseconds.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from membrane_models.live import ModalEngine, ModalState, Probe
from membrane_models.problems import make_problem

FloatArray = NDArray[np.float64]

# (label, problem, lattice, dt, probe circle centre)
CASES = [
    ("membrane 20 x 20, dt 1 ms, probe in the middle", "membrane-forced", 20, 0.001, (0.5, 0.5)),
    ("membrane 20 x 20, dt 1 ms, probe near an edge", "membrane-forced", 20, 0.001, (0.2, 0.5)),
    ("membrane 20 x 20, dt 10 ms (display rate)", "membrane-forced", 20, 0.01, (0.5, 0.5)),
    ("membrane 100 x 100, dt 1 ms, probe in the middle", "membrane-forced", 100, 0.001, (0.5, 0.5)),
    ("membrane 100 x 100, dt 10 ms (display rate)", "membrane-forced", 100, 0.01, (0.5, 0.5)),
    ("rope 100, dt 1 ms", "string-forced", 100, 0.001, (0.5,)),
]


def probe_at(centre: tuple[float, ...], k: int) -> Probe:
    """The k-th position on a circle of radius 0.1 (a segment on the string)."""
    angle = 2.0 * math.pi * k / 1000.0
    if len(centre) == 1:
        return Probe((centre[0] + 0.1 * math.sin(angle),), 1e-5, 0.05)
    at = (centre[0] + 0.1 * math.cos(angle), centre[1] + 0.1 * math.sin(angle))
    return Probe(at, 1e-5, 0.05)


def baseline(engine: ModalEngine) -> tuple[str, Callable[[], object]]:
    """The bare numpy synthesis of a frame of the engine's size."""
    rng = np.random.default_rng(0)
    points = math.prod(engine.lattice_shape)
    modes = engine.modes.count
    if points * modes * 8 <= 64 * 2**20:
        matrix = rng.standard_normal((points, modes))
        vector = rng.standard_normal(modes)
        return f"matvec {points} x {modes}", lambda: matrix @ vector
    nx, ny = engine.lattice_shape
    kx, ky = engine.modes.box
    tx, ty = rng.standard_normal((nx, kx)), rng.standard_normal((ny, ky))
    q = rng.standard_normal((kx, ky))
    return f"T_x Q T_y^T ({nx}x{kx}, {kx}x{ky})", lambda: tx @ q @ ty.T


def measure(
    engine: ModalEngine, centre: tuple[float, ...], calls: int, frame: bool
) -> tuple[FloatArray, FloatArray]:
    """Per-call microseconds of the step and of the baseline, interleaved."""
    _, bare = baseline(engine)
    state: ModalState = engine.start().state
    warm = calls // 10
    step_us, base_us = np.empty(calls), np.empty(calls)
    for k in range(warm + calls):
        probe = probe_at(centre, k)
        started = time.perf_counter()
        result = engine.step(state, (), [probe], frame=frame)
        middle = time.perf_counter()
        bare()
        ended = time.perf_counter()
        state = result.state
        if k >= warm:
            step_us[k - warm] = (middle - started) * 1e6
            base_us[k - warm] = (ended - middle) * 1e6
    return step_us, base_us


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20000, help="timed steps per row")
    args = parser.parse_args()
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    print(f"OPENBLAS_NUM_THREADS={threads}, {args.calls} timed steps per 20 x 20 row\n")
    print("| case | modes | what | step p50 / p99 (us) | baseline | p50 / p99 | ratio p50 / p99 |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, name, n, dt, centre in CASES:
        problem = make_problem(name)
        engine = ModalEngine(problem, n, dt)
        calls = args.calls if n <= 20 or problem.spatial_dims == 1 else max(1000, args.calls // 4)
        what, _ = baseline(engine)
        for frame in (False, True):
            step_us, base_us = measure(engine, centre, calls, frame)
            s50, s99 = np.percentile(step_us, [50, 99])
            b50, b99 = np.percentile(base_us, [50, 99])
            kind = "step + frame" if frame else "step (haptic)"
            print(
                f"| {label} | {engine.modes.count} | {kind} | {s50:.1f} / {s99:.1f} | {what} | "
                f"{b50:.1f} / {b99:.1f} | {s50 / b50:.2f} / {s99 / b99:.2f} |"
            )


if __name__ == "__main__":
    main()
