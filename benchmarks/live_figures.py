"""The live engine's accuracy figures, for docs/LIVE.md: every table printed from one run.

1. Film agreement: the engine driven by the `membrane` and `rope` scenes' forcing (one Gaussian
   load at the force's centre, first-order hold) against the exact film on the scene's lattice,
   relative L2 over the lattice x the frames t = dt .. 1: truncation-free (every mode the force
   excites, no correction needed), the kept modes with the static correction, and without it.
2. Energy (undamped, zero-order hold, kept modes): the worst per-step |dE - W| / E under a load
   and a probe; the drift of E without input over N steps; damped, the largest per-step growth.
3. Probe force under a slowly pressed probe as modes are added, with and without the static
   correction, against a 100 x 100-mode reference (relative L2 over the force history).
4. Static limits: a held load, damped, against the string's closed form and the membrane's
   Poisson sum.

    python benchmarks/live_figures.py            # 10^5 free steps for the drift (about a minute)
    python benchmarks/live_figures.py --long     # 10^6, as the issue asks (several minutes)
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from numpy.typing import NDArray

from membrane_models.exact.forced import forced_modal_solution
from membrane_models.exact.spectrum import gaussian_sine_integrals
from membrane_models.live import Load, ModalEngine, Probe, film_frames
from membrane_models.live.static_correction import string_green
from membrane_models.problems import MembraneForced, Problem, StringForced, make_problem

FloatArray = NDArray[np.float64]
SCENES = {"membrane": ("membrane-forced", 20), "rope": ("string-forced", 100)}
STEPS = (0.01, 0.005, 0.0025)


def lattice_points(shape: tuple[int, ...]) -> FloatArray:
    axes = [np.linspace(0.0, 1.0, n) for n in shape]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(shape))


def film_error(engine: ModalEngine, problem: StringForced | MembraneForced) -> float:
    """Relative L2 of the engine's frames against the exact film over t = dt .. 1."""
    exact = forced_modal_solution(problem).on_points(lattice_points(engine.lattice_shape))
    steps = round(1.0 / engine.dt)
    error = reference = 0.0
    for index, frame in enumerate(film_frames(engine, problem, steps), start=1):
        truth = exact(index * engine.dt)
        error += float(((frame - truth) ** 2).sum())
        reference += float((truth**2).sum())
    return math.sqrt(error / reference)


def film_table() -> None:
    print("### Film agreement (first-order hold; relative L2 over lattice x frames)\n")
    print("| scene | dt | truncation-free | kept + correction (modes) | ratio | no correction |")
    print("| --- | --- | --- | --- | --- | --- |")
    for scene, (name, n) in SCENES.items():
        problem = make_problem(name)
        assert isinstance(problem, StringForced | MembraneForced)
        free_modes = 80 if problem.spatial_dims == 2 else 200
        for dt in STEPS:
            free = ModalEngine(problem, n, dt, hold="foh", modes=free_modes, step_limit=None)
            kept = ModalEngine(problem, n, dt, hold="foh")
            bare = ModalEngine(problem, n, dt, hold="foh", static_correction=False)
            e_free, e_kept, e_bare = (film_error(e, problem) for e in (free, kept, bare))
            print(
                f"| {scene} | {dt} | {e_free:.3e} | {e_kept:.3e} ({kept.modes.count}) | "
                f"{e_kept / e_free:.4f} | {e_bare:.3e} |"
            )
    print()


def energy_table(free_steps: int) -> None:
    print("### Energy (kept modes, zero-order hold)\n")
    problem = make_problem("membrane-forced")
    engine = ModalEngine(problem, 20, 0.001)
    state = engine.start().state
    worst = 0.0
    for k in range(2000):  # a load switched on, then a probe pressing and releasing
        load = Load((0.7, 0.4), 0.01 * math.sin(0.01 * k), 0.05)
        probe = Probe((0.35, 0.55), 1e-5 * (1.0 + math.sin(0.02 * k)), 0.05)
        before = engine.energy(state)
        result = engine.step(state, [load], [probe], frame=False, work=True)
        state = result.state
        assert result.work is not None
        after = engine.energy(state)
        if after > 0.0:
            worst = max(worst, abs(after - before - result.work) / after)
    print("| quantity | value |")
    print("| --- | --- |")
    print(f"| max per-step abs(dE - W) / E, 2000 steps, load + probe, 20 x 20 | {worst:.2e} |")
    start_energy = engine.energy(state)
    started = time.perf_counter()
    for _ in range(free_steps):
        state = engine.step(state, frame=False).state
    drift = abs(engine.energy(state) / start_energy - 1.0)
    seconds = time.perf_counter() - started
    print(f"| abs(E_N / E_0 - 1), no input, N = {free_steps} | {drift:.2e} ({seconds:.0f} s) |")
    damped = ModalEngine(problem, 20, 0.001, damping=0.02)
    state = damped.start(displacement=_shape(20)).state
    growth = -math.inf
    for _ in range(20000):
        before = damped.energy(state)
        state = damped.step(state, frame=False).state
        growth = max(growth, damped.energy(state) / before - 1.0)
    print(f"| damped (zeta 0.02), largest per-step E_n+1 / E_n - 1, 20000 steps | {growth:.2e} |")
    print()


def _shape(n: int) -> FloatArray:
    """A smooth initial displacement on an n x n lattice (zero on the edges)."""
    x = np.linspace(0.0, 1.0, n)
    bump = np.sin(np.pi * x) ** 2 * x
    return np.asarray(1e-4 * np.outer(bump, np.sin(2 * np.pi * x)))


def probe_table() -> None:
    print("### Probe force as modes are added (membrane, r = 0.05 at (0.35, 0.55))\n")
    problem = make_problem("membrane-forced")
    dt, steps, ramp = 0.002, 300, 0.3

    def history(**options: object) -> FloatArray:
        engine = ModalEngine(problem, 20, dt, **options)  # type: ignore[arg-type]
        state = engine.start().state
        forces = []
        for k in range(1, steps + 1):
            t = min(k * dt, ramp)
            probe = Probe((0.35, 0.55), 1e-4 * 0.5 * (1.0 - math.cos(math.pi * t / ramp)), 0.05)
            result = engine.step(state, (), [probe], frame=False)
            state = result.state
            forces.append(result.probes[0].force)
        return np.array(forces)

    reference = history(modes=100, step_limit=None)
    print("| modes per axis | with correction | without | final force, with / without |")
    print("| --- | --- | --- | --- |")
    for m in (2, 4, 8, 16, 32, 64):
        with_c = history(modes=m, step_limit=None)
        without = history(modes=m, step_limit=None, static_correction=False)
        e_with = float(np.linalg.norm(with_c - reference) / np.linalg.norm(reference))
        e_without = float(np.linalg.norm(without - reference) / np.linalg.norm(reference))
        print(
            f"| {m} | {e_with:.2e} | {e_without:.2e} | "
            f"{with_c[-1] / reference[-1]:.4f} / {without[-1] / reference[-1]:.4f} |"
        )
    print(f"\nReference: 100 x 100 modes, final force {reference[-1]:.6g} (depth 1e-4).\n")


def static_table() -> None:
    print("### Static limits (damped zeta = 0.7, dt = 0.05, display-rate mode rule)\n")
    print("| case | modes stepped | with correction | without |")
    print("| --- | --- | --- | --- |")
    string = make_problem("string-forced")
    truth = 0.3 * string_green(np.linspace(0.0, 1.0, 100), 0.37, string.c)
    _static_row("string, point load 0.3 at x = 0.37", string, 100, Load((0.37,), 0.3, 0.0), truth)
    membrane = make_problem("membrane-forced")
    for at, radius, what in (
        ((0.3, 0.6), 0.05, ""),
        ((0.97, 0.04), 0.05, ", a corner cuts it"),
        ((0.0, 0.5), 0.05, ", centre on an edge"),
        ((0.5, 0.5), 5.0, ", wider than the domain"),
    ):
        truth = 0.2 * poisson_sum(membrane.c, at, radius, 20, modes=1024)
        case = f"membrane, load 0.2, r = {radius} at {at}{what}"
        _static_row(case, membrane, 20, Load(at, 0.2, radius), truth)
    print(
        "\nReferences: the string's Green's function; the membrane's mode sum to 1024 per axis.\n"
    )


def _static_row(case: str, problem: Problem, n: int, load: Load, truth: FloatArray) -> None:
    errors = []
    for corrected in (True, False):
        engine = ModalEngine(problem, n, 0.05, damping=0.7, static_correction=corrected)
        frame = _held(engine, load)
        errors.append(float(np.abs(frame - truth).max() / np.abs(truth).max()))
    print(f"| {case} | {engine.modes.count} | {errors[0]:.1e} | {errors[1]:.1e} |")


def _held(engine: ModalEngine, load: Load, steps: int = 400) -> FloatArray:
    state = engine.start().state
    for _ in range(steps - 1):
        state = engine.step(state, [load], frame=False).state
    frame = engine.step(state, [load]).frame
    assert frame is not None
    return frame


def poisson_sum(
    c: float, at: tuple[float, float], radius: float, n: int, modes: int = 200
) -> FloatArray:
    """Static deflection per unit force of a Gaussian footprint on the unit square (n x n
    lattice): sum_mn s_mn sin sin / (c pi)^2 (m^2 + n^2), from the closed-form sine integrals."""
    m = np.arange(1, modes + 1)
    scale = 2.0 / (math.sqrt(math.pi) * radius)
    sx = scale * gaussian_sine_integrals(m, at[0], 1.0 / radius**2)
    sy = scale * gaussian_sine_integrals(m, at[1], 1.0 / radius**2)
    weights = 1.0 / ((c * math.pi) ** 2 * (m[:, None] ** 2 + m[None, :] ** 2))
    table = np.sin(np.pi * np.outer(np.linspace(0.0, 1.0, n), m))
    return np.asarray((table @ (np.outer(sx, sy) * weights) @ table.T).reshape(-1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long", action="store_true", help="10^6 free steps for the drift")
    args = parser.parse_args()
    film_table()
    energy_table(10**6 if args.long else 10**5)
    probe_table()
    static_table()


if __name__ == "__main__":
    main()
