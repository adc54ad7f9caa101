"""The nonlinear string live (`rope-nonlinear`, ``live.kirchhoff``): its error against the
Galerkin reference and the finite-difference cross-check, its energy, and its step cost beside
the linear rope's (docs/NONLINEAR.md, "The nonlinear string, live").

    python benchmarks/kirchhoff_live.py [--repeats 5]

The string of the scene: c = 1, k = 100, 130 lattice points (128 sine modes), from rest in the
shape 0.03 sin(pi x) + 0.01 sin(3 pi x) + 0.004 sin(5 pi x) (nonlinearity k S* / c^2 = 1.09,
the strong band of the Koopman datasets).

1. After 1 s, the modal amplitudes against the Galerkin reference (``exact.kirchhoff_carrier``,
   DOP853 at rtol 1e-13, the same modes) at dt = 4, 2, 1 (the scene's) and 0.5 ms: relative
   L2 error and observed order; the linear engine (exact linear steps) for scale.
2. The finite-difference cross-check (``checks.kirchhoff_fd``: leapfrog on 129, 258 and 516
   cells) against the same reference on the lattice points: the error of an independent solver
   of the PDE, and its order in dx.
3. The energy over 10^4 steps without damping or input (its spread).
4. The step's cost in-process, microseconds, median of ``--repeats`` runs of 2,000 steps each
   (each run continuing from the same ringing state under the input held, as a haptic loop
   steps; its first step is the impact), the nonlinear rope, the linear rope, the linear rope
   by the stepping core's general path (``GeneralPath``: as the nonlinear rope's steps go; the
   linear rope's load-only steps take the core's batched free step) and the nonlinear rope's
   numpy path (``compiled=False``: what it steps by without numba) side by side, their
   runs interleaved 100 steps at a time (the other jobs on a shared machine weigh on each
   alike): a free step with its frame, a probe, a load, a grasp and a rigid tool.
   ``--costs-only``: this part alone.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from membrane_models.checks.kirchhoff_fd import solve_kirchhoff_fd
from membrane_models.exact.kirchhoff_carrier import KirchhoffString, solve_kirchhoff
from membrane_models.live import ModalEngine
from membrane_models.live.interface import Grasp, Load, Probe, Tool
from membrane_models.live.kirchhoff import KirchhoffEngine
from membrane_models.problems import StringKirchhoff

X = np.linspace(0.0, 1.0, 130)
MODES = np.zeros(128)
MODES[[0, 2, 4]] = 0.03, 0.01, 0.004
STRING = KirchhoffString(1.0, 100.0)


def shape(x: np.ndarray) -> np.ndarray:
    return np.sin(np.outer(x, np.pi * np.arange(1, 129))) @ MODES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--costs-only", action="store_true", help="the step costs alone")
    args = parser.parse_args()
    if args.costs_only:
        costs(args.repeats)
        return
    print(f"nonlinearity k S* / c^2 = {float(STRING.nonlinearity(MODES, np.zeros(128))):.3f}")
    reference = solve_kirchhoff(STRING, MODES, np.zeros(128), [0.0, 1.0])
    expected = reference.q[-1]
    galerkin(expected)
    finite_differences(reference)
    energy()
    costs(args.repeats)


def galerkin(expected: np.ndarray) -> None:
    print("\n| dt (ms) | rel. L2 of q at t = 1 s | observed order |")
    print("| --- | --- | --- |")
    last = None
    for dt in (4e-3, 2e-3, 1e-3, 5e-4):
        engine = KirchhoffEngine(StringKirchhoff(), 130, dt)
        state = engine.start(shape(X)).state
        for _ in range(round(1.0 / dt)):
            state = engine.step(state, frame=False).state
        error = float(np.linalg.norm(state.q - expected) / np.linalg.norm(expected))
        order = "" if last is None else f"{math.log2(last / error):.2f}"
        print(f"| {dt * 1e3:g} | {error:.3e} | {order} |")
        last = error
    linear = ModalEngine(StringKirchhoff(), 130, 1e-3)
    state = linear.start(shape(X)).state
    for _ in range(1000):
        state = linear.step(state, frame=False).state
    error = float(np.linalg.norm(state.q - expected) / np.linalg.norm(expected))
    print(f"| 1, the linear engine (exact linear steps) | {error:.3e} | |")


def finite_differences(reference: object) -> None:
    u_ref = np.asarray(reference.at_points(X)[0][-1])  # type: ignore[attr-defined]
    print("\n| FD cells | rel. L2 of u at t = 1 s on the lattice | observed order |")
    print("| --- | --- | --- |")
    last = None
    for cells in (129, 258, 516):
        fd = solve_kirchhoff_fd(STRING, shape, lambda x: np.zeros_like(x), cells, [0.0, 1.0])
        u = np.interp(X, fd.axes[0], fd.u[:, -1])
        error = float(np.linalg.norm(u - u_ref) / np.linalg.norm(u_ref))
        order = "" if last is None else f"{math.log2(last / error):.2f}"
        print(f"| {cells} | {error:.3e} | {order} |")
        last = error


def energy() -> None:
    engine = KirchhoffEngine(StringKirchhoff(), 130, 1e-3)
    state = engine.start(shape(X)).state
    start = engine.energy(state)
    energies = np.empty(10_000)
    for k in range(energies.size):
        state = engine.step(state, frame=False).state
        energies[k] = engine.energy(state)
    spread = (energies.max() - energies.min()) / start
    print(f"\nenergy over 10^4 steps (10 s), no damping: spread {spread:.2e} of the start's")


class GeneralPath(ModalEngine):
    """The linear rope stepped by the core's general path (an engine with its own
    ``_solve_step`` takes no batched load step), with the core's own transition."""

    def _solve_step(self, state, advance, constrained, rows=None):  # type: ignore[no-untyped-def]
        return advance(self.transition)


def costs(repeats: int) -> None:
    cases: dict[str, dict[str, list[object]]] = {
        "free, with frame": {},
        "probe": {"probes": [Probe((0.3,), 0.01, 0.02)]},
        "load": {"loads": [Load((0.3,), 0.5, 0.02)]},
        "grasp": {"grasps": [Grasp((0.3,), 0.02, 0.02)]},
        "sphere tool": {"tools": [Tool("sphere", (0.3,), 0.01, 0.02)]},
    }
    nonlinear = KirchhoffEngine(StringKirchhoff(), 130, 1e-3)
    engines: dict[str, ModalEngine] = {"nonlinear": nonlinear,
                                       "linear": ModalEngine(StringKirchhoff(), 130, 1e-3),
                                       "general": GeneralPath(StringKirchhoff(), 130, 1e-3),
                                       "numpy": KirchhoffEngine(StringKirchhoff(), 130, 1e-3,
                                                                compiled=False)}  # fmt: skip
    states: dict[str, object] = {}
    for name, engine in engines.items():
        state = engine.start(shape(X)).state
        for _ in range(200):
            state = engine.step(state).state
        states[name] = state
    compiled = "compiled" if nonlinear.compiled else "numpy (numba is not installed)"
    print(f"\nthe nonlinear rope's step: {compiled}")
    print("\n| step | nonlinear (us) | linear (us) | ratio | linear, general path (us) | ratio "
          "| numpy path (us) | ratio |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for case, inputs in cases.items():
        figures: dict[str, list[float]] = {name: [] for name in engines}
        for _ in range(repeats):
            for name, cost in _run_costs(engines, states, inputs).items():
                figures[name].append(cost)
        ours, theirs, general, numpy_path = (float(np.median(figures[name])) for name in engines)
        print(f"| {case} | {ours:.0f} | {theirs:.0f} | {ours / theirs:.2f} | {general:.0f} "
              f"| {ours / general:.2f} | {numpy_path:.0f} "
              f"| {numpy_path / theirs:.2f} |")  # fmt: skip


def _run_costs(
    engines: dict[str, ModalEngine],
    states: dict[str, object],
    inputs: dict[str, list[object]],
    steps: int = 2000,
    chunk: int = 100,
) -> dict[str, float]:
    """Microseconds a step of each engine over ``steps`` steps continuing from its state under
    ``inputs`` held (what a haptic loop does: the first step of a press, its impact, is one
    of them), the engines taking ``chunk`` steps in turn."""
    elapsed = dict.fromkeys(engines, 0.0)
    current = dict(states)
    for _ in range(steps // chunk):
        for name, engine in engines.items():
            state = current[name]
            began = time.perf_counter()
            for _ in range(chunk):
                state = engine.step(state, **inputs).state  # type: ignore[arg-type]
            elapsed[name] += time.perf_counter() - began
            current[name] = state
    return {name: seconds / steps * 1e6 for name, seconds in elapsed.items()}


if __name__ == "__main__":
    main()
