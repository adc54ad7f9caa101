"""The live cost model against the clock: the estimated work of a step (``cost.step_cost``)
and the measured time of that step and of its state's frame, with footprints from the study's
radius down to the smallest, on the built-in live scenes.

    python benchmarks/live_cost.py

Per case: the estimate (ms), the measured step and frame (best of 3, ms; loads moved by a hair
each run so that no cached spectrum helps) and their ratio measured / estimated. The model is
honest when the ratio stays at or below about 1 wherever the time matters, so the budget
(describe's ``live.max_step_work``) bounds what a step really costs on this machine.
"""

from __future__ import annotations

import time
from dataclasses import replace

from membrane_models.live import Load, ModalEngine, ModalState, Probe
from membrane_models.live.cost import StepBudget, step_cost
from membrane_server.served import ServedScene

_TOO_SLOW_TO_TIME = 60e6  # work units (about 60 ms)


def cases(dims: int, min_radius: float) -> list[tuple[str, list[Load], list[Probe]]]:
    def at(i: int, spread: float = 0.005) -> tuple[float, ...]:
        return (0.3 + spread * i,) * dims

    out = []
    for radius in (0.05, 0.01, 4 * min_radius, 2 * min_radius, min_radius):
        for loads, probes in ((1, 0), (8, 0), (64, 0), (0, 1), (8, 8), (64, 8)):
            name = f"r={radius:.3g} loads={loads} probes={probes}"
            ld = [Load(at(i), 1.0, radius) for i in range(loads)]
            pr = [Probe(at(i, 0.05), 1e-3, radius) for i in range(probes)]
            out.append((name, ld, pr))
    centre = (0.5,) * dims
    out.append(("edge r=1 loads=1", [Load(centre, 1.0, 1.0)], []))
    out.append(("edge r=10 loads=8", [Load(centre, 1.0, 10.0)] * 8, []))
    return out


def timed_step(
    engine: ModalEngine, start: ModalState, loads: list[Load], probes: list[Probe]
) -> float:
    best = float("inf")
    for run in range(1, 4):
        moved = [replace(x, at=tuple(a + run * 1e-9 for a in x.at)) for x in loads]
        started = time.perf_counter()
        engine.step(start, moved, probes, frame=False)
        best = min(best, time.perf_counter() - started)
    return best


def timed_frame(engine: ModalEngine, state: ModalState) -> float:
    best = float("inf")
    for _ in range(3):
        started = time.perf_counter()
        engine.frame(state)
        best = min(best, time.perf_counter() - started)
    return best


def report(scene: str) -> None:
    engine = ServedScene.load(scene).live
    assert isinstance(engine, ModalEngine)
    unlimited = ModalEngine(
        engine.problem, engine.lattice_shape, engine.dt, damping=engine.damping,
        budget=StepBudget(float("inf"), 2**62),
    )  # fmt: skip
    start = unlimited.start().state
    print(f"{scene}: budget {engine.budget.max_work / 1e6:g} ms")
    print(f"{'case':40} {'estimate':>9} {'step':>9} {'frame':>9} {'ratio':>6} {'held':>9}")
    for name, loads, probes in cases(engine.spatial_dims, engine.min_radius):
        sizes = [unlimited.footprint_size(Load(x.at, 1.0, x.radius), "load", 0) for x in loads]
        inside = [unlimited.footprint_size(Probe(x.at, 0.0, x.radius), "probe", 0) for x in probes]
        cost = step_cost(sizes, inside, unlimited.lattice_shape, True)
        if cost.work > _TOO_SLOW_TO_TIME:
            print(f"{name:40} {cost.work / 1e6:9.3f}   (refused; too slow to time)")
            continue
        state = unlimited.step(start, loads, probes, frame=False).state
        step, frame = timed_step(unlimited, start, loads, probes), timed_frame(unlimited, state)
        ratio = (step + frame) * 1e9 / cost.work
        verdict = "" if cost.work <= engine.budget.max_work else " (refused)"
        print(
            f"{name:40} {cost.work / 1e6:9.3f} {step * 1e3:9.3f} {frame * 1e3:9.3f} "
            f"{ratio:6.2f} {cost.held_bytes:9d}{verdict}"
        )


if __name__ == "__main__":
    for name in ("membrane-live", "rope-live"):
        report(name)
