"""A live step on FEM modes against a step of the sine engine, side by side in one run.

FEM: the study's skin patch (50 mm square, clamped, E 1.5 MPa, nu 0.45, rho 1109 kg/m^3,
h 3 mm; Argyris, 2.5 mm elements), 100 modes with the static correction, a 20 x 20 lattice, one
probe of radius 2.5 mm at an interior point. Sine: the membrane engine at 100 modes (10 x 10,
a 12 x 12 lattice), one probe of radius 0.05 (2.5 mm on a 50 mm side) at the same relative
point. Both in-process, a frame every step, the probe pressing 10 um (in contact) and moving a
little every step so no cache helps; the two are timed in alternating blocks so that load on
the machine weighs on both alike. Prints p50 and p99 (us) and their ratios.

    python benchmarks/fem_live_step.py [--steps 20000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from membrane_models import fem
from membrane_models.fem.cache import TableCache, cached_tables
from membrane_models.fem.live_basis import fem_basis
from membrane_models.live import ModalEngine, Probe
from membrane_models.live.stepper import ModalStepper
from membrane_models.problems import make_problem

SIDE = 0.05
SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20_000, help="steps per engine")
    parser.add_argument("--block", type=int, default=500, help="steps per alternating block")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        started = time.perf_counter()
        tables, _ = cached_tables(
            fem.rectangle(SIDE, SIDE, 0.0025), SKIN, "clamped", count=100, lattice=(20, 20),
            radii=[0.0025], cache=TableCache(Path(directory)),
        )  # fmt: skip
        seconds = time.perf_counter() - started
        print(f"FEM tables (cold): {seconds:.2f} s, {tables.nbytes / 1e6:.1f} MB")
    physical = ModalStepper(fem_basis(tables), 1e-3, damping=0.02)
    sine = ModalEngine(make_problem("membrane-forced"), 12, 1e-3, damping=0.02, step_limit=None)
    assert physical.modes.count == 100 and sine.modes.count == 100
    engines: dict[str, tuple[ModalStepper[Any], Callable[[int], Probe]]] = {
        "fem": (physical, lambda k: Probe((0.02 + 1e-6 * (k % 97), 0.027), 1e-5, 0.0025)),
        "sine": (sine, lambda k: Probe((0.4 + 2e-5 * (k % 97), 0.54), 1e-5 / SIDE, 0.05)),
    }
    times: dict[str, list[float]] = {name: [] for name in engines}
    states = {name: engine.start().state for name, (engine, _) in engines.items()}
    clock = time.perf_counter
    for block in range(0, args.steps, args.block):
        for name, (engine, probe) in engines.items():
            state, spent = states[name], times[name]
            for k in range(block, block + args.block):
                begin = clock()
                result = engine.step(state, (), [probe(k)])
                spent.append(clock() - begin)
                state = result.state
            states[name] = state
            assert result.probes[0].in_contact
    p = {name: np.percentile(np.array(t) * 1e6, [50, 99]) for name, t in times.items()}
    print("| engine | modes | lattice | p50 (us) | p99 (us) |")
    print("| --- | --- | --- | --- | --- |")
    for name, (engine, _) in engines.items():
        lattice = "x".join(map(str, engine.lattice_shape))
        print(
            f"| {name} | {engine.modes.count} | {lattice} | {p[name][0]:.1f} | {p[name][1]:.1f} |"
        )
    ratio = p["fem"] / p["sine"]
    print(f"FEM / sine: p50 {ratio[0]:.2f}x, p99 {ratio[1]:.2f}x (target <= 1.5x)")


if __name__ == "__main__":
    main()
