"""FEM modes stepped by the live core: the dynamic figures of docs/FEM.md.

The study's skin-patch plate (50 mm square, E 1.5 MPa, nu 0.45, rho 1109 kg/m^3, h 3 mm) on the
6.25 mm Argyris mesh the tests use, a 1 N load of radius 2.5 mm suddenly applied at the centre:

1. simply supported, every mode stepped: the peak at t = pi / w_11 over the static deflection;
2. the same with 12 and 30 modes stepped and the static correction of the rest;
3. clamped, every mode stepped: the first maximum;
4. a half-cosine ramp over ten first periods (damping 0.05): the final over the static value;
5. every mode stepped against a direct Newmark (average acceleration) integration of the FEM
   system over 0.1 s, relative L2 over the lattice's history, at three Newmark steps.

    python benchmarks/fem_dynamics.py
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from scipy.sparse.linalg import splu

from membrane_models import fem
from membrane_models.fem.live_basis import fem_basis
from membrane_models.fem.tables import LiveTables, footprint_loads, lattice_points, live_tables
from membrane_models.live import Load
from membrane_models.live.stepper import ModalStepper

SKIN = fem.Plate(youngs_modulus=1.5e6, poisson=0.45, thickness=0.003, density=1109.0)
SIDE, RADIUS, CENTRE, LATTICE, MIDDLE = 0.05, 0.0025, (0.025, 0.025), (9, 9), 40


def patch(supports: str) -> tuple[fem.System, float]:
    system = fem.assemble(fem.rectangle(SIDE, SIDE, 0.00625), SKIN, supports)
    load = footprint_loads(system, RADIUS, np.array([CENTRE]))[:, 0]
    return system, float(fem.sample(system, fem.solve(system, load), CENTRE))


def centre(
    tables: LiveTables,
    dt: float,
    steps: int,
    force: Callable[[float], float] = lambda t: 1.0,
    damping: float = 0.0,
) -> np.ndarray:
    engine = ModalStepper(fem_basis(tables), dt, damping=damping)
    state, out = engine.start().state, []
    for index in range(1, steps + 1):
        result = engine.step(state, [Load(CENTRE, force(index * dt), RADIUS)])
        state = result.state
        assert result.frame is not None
        out.append(result.frame[MIDDLE])
    return np.array(out)


def newmark_error(
    system: fem.System, modes: fem.Modes, tables: LiveTables, per_period: int
) -> float:
    sampled = fem.sampler(
        system, lattice_points(tables.lower, tables.upper, LATTICE)[tables.inside]
    )
    load = system.reduce(footprint_loads(system, RADIUS, np.array([CENTRE]))[:, 0])
    k, m = system.reduced_stiffness, system.reduced_mass
    steps = round(0.1 / (2 * math.pi / modes.omega[0] / per_period))
    dt = 0.1 / steps
    effective = splu((k + 4 / dt**2 * m).tocsc())
    x, v, a = np.zeros(system.free), np.zeros(system.free), splu(m.tocsc()).solve(load)
    direct = []
    for _ in range(steps):
        x_new = effective.solve(load + m @ (4 / dt**2 * x + 4 / dt * v + a))
        v_new = 2 / dt * (x_new - x) - v
        a = 4 / dt**2 * (x_new - x) - 4 / dt * v - a
        x, v = x_new, v_new
        direct.append(sampled @ system.expand(x))
    engine = ModalStepper(fem_basis(tables), dt)
    state, modal = engine.start().state, []
    for _ in range(steps):
        result = engine.step(state, [Load(CENTRE, 1.0, RADIUS)])
        state = result.state
        assert result.frame is not None
        modal.append(result.frame[tables.inside])
    return float(np.linalg.norm(np.array(direct) - np.array(modal)) / np.linalg.norm(modal))


def main() -> None:
    started = time.perf_counter()
    system, static = patch("simply_supported")
    every = fem.modes(system, system.free)
    tables = live_tables(system, every, LATTICE, [RADIUS], static_correction=False)
    dt = math.pi / every.omega[0] / 200
    history = centre(tables, dt, 400)
    print("| case | modes stepped | result |")
    print("| --- | --- | --- |")
    peak = int(np.argmax(history))
    print(f"| simply supported, step load: peak / static | all {every.count} | "
          f"{history[peak] / static:.5f} at t = {(peak + 1) / 200:.3f} pi / w_11 |")  # fmt: skip
    for count in (12, 30):
        some = fem.modes(system, count)
        corrected = live_tables(system, some, LATTICE, [RADIUS])
        value = float(np.max(centre(corrected, math.pi / some.omega[0] / 200, 400))) / static
        case = "simply supported, step load, static correction: peak / static"
        print(f"| {case} | {count} | {value:.5f} |")
    clamped, clamped_static = patch("clamped")
    clamped_modes = fem.modes(clamped, clamped.free)
    clamped_tables = live_tables(clamped, clamped_modes, LATTICE, [RADIUS], static_correction=False)
    history = centre(clamped_tables, math.pi / clamped_modes.omega[0] / 200, 300)
    first = int(np.argmax(history[:260]))
    ratio, when = history[first] / clamped_static, (first + 1) / 200
    case = "clamped, step load: first maximum / static"
    print(f"| {case} | all {clamped_modes.count} | {ratio:.5f} at t = {when:.3f} pi / w_11 |")
    period = 2 * math.pi / every.omega[0]
    ramp = 10 * period
    slow = centre(
        tables,
        period / 100,
        1200,
        lambda t: 0.5 * (1 - math.cos(math.pi * min(t, ramp) / ramp)),
        0.05,
    )
    case = "simply supported, ramp over 10 periods, zeta 0.05: final / static"
    print(f"| {case} | all | {slow[-1] / static:.5f} |")
    for per_period in (400, 1000, 2000):
        error = newmark_error(system, every, tables, per_period)
        case = f"against Newmark, {per_period} steps per first period, 0.1 s: relative L2"
        print(f"| {case} | all | {error:.2e} |")
    print(f"({system.free} free DOFs; {time.perf_counter() - started:.1f} s)")


if __name__ == "__main__":
    main()
