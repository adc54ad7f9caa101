"""The skin patch at large deflection: the reduced von Karman plate against the full one, and
what each way of answering costs (docs/NONLINEAR.md, "The trade-off").

    python benchmarks/nonlinear_tradeoff.py [--modes 8,12,16,20,30] [--out runs/nonlinear.json]
    python benchmarks/nonlinear_tradeoff.py --modes 20 --costs-only --repeat 3   # step cost only

On `skin-patch-nonlinear`'s mesh (the study's 50 mm clamped patch, 2.5 mm elements, edges held
in their plane) and lattice (20 x 20):

1. Static presses to 6 mm (2 h) of a flat punch and of a sphere, both 5 mm in radius, at the
   centre and off it at (19, 31) mm: the full plate (``fem.nonlinear_press``: Newton with the
   tool's lattice points constrained, on every DOF) against the reduced plate at each mode
   count (``fem.reduced_dynamics.press_reduced``, the same points) and the linear plate (the
   same points held on the mesh: what the linear engines converge to).
2. The cost of a step at 1 kHz, in-process: the reduced engine during a slow press of the
   sphere to 6 mm (3,000 steps, a tool per step, no frame), `skin-patch`'s linear engine
   under the same press, and one Newmark + Newton step of the full plate
   (``fem.nonlinear_transient``).

The modes' basis is built from no load: the validation presses differ from anything used to
build it. Prints markdown tables and writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from membrane_models import fem
from membrane_models.fem.contact import solve_obstacle
from membrane_models.fem.nonlinear_engine import NonlinearPlateEngine
from membrane_models.fem.nonlinear_press import press_nonlinear
from membrane_models.fem.nonlinear_transient import step_nonlinear
from membrane_models.fem.reduced_dynamics import press_reduced
from membrane_models.fem.reduced_plate import ReducedPlate, reduce_plate
from membrane_models.fem.sampling import sampler
from membrane_models.live.interface import Tool
from membrane_models.live.tools import ToolPoints, tool_points
from membrane_server.live import build_scene_engine
from membrane_server.scene import load_scene
from membrane_server.tissue_scene import tissue_parts

DEPTHS = (0.001, 0.002, 0.003, 0.004, 0.005, 0.006)
PLACES = {"centre": (0.025, 0.025), "off centre": (0.019, 0.031)}
KINDS = ("cylinder", "sphere")
RADIUS = 0.005


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", default="8,12,16,20,30")
    parser.add_argument("--out", type=Path, default=Path("runs/nonlinear-tradeoff.json"))
    parser.add_argument("--costs-only", action="store_true", help="the step costs (part 2) only")
    parser.add_argument("--repeat", type=int, default=1, help="the cost table this many times")
    args = parser.parse_args()
    counts = [int(c) for c in args.modes.split(",")]
    scene = load_scene("skin-patch-nonlinear")
    tissue, _, _ = tissue_parts(scene)
    system = fem.assemble(tissue.domain, tissue.model, tissue.supports, tissue.element)
    print(f"mesh: {system.dofs} plate DOFs, lattice {scene.lattice.shape}", flush=True)
    plates: dict[int, ReducedPlate] = {}
    builds = {}
    for count in counts:
        began = time.perf_counter()
        plates[count] = reduce_plate(system, count, (20, 20), "held")
        builds[count] = time.perf_counter() - began
        print(f"reduced plate, {count} modes: built in {builds[count]:.1f} s", flush=True)
    if args.costs_only:
        for _ in range(args.repeat):
            cost_table(scene, tissue, plates)
        return
    presses = press_table(system, plates)
    costs = cost_table(scene, tissue, plates)
    full_step = full_step_cost(system)
    print(f"\nfull plate, one Newmark + Newton step at 1 ms: {full_step:.2f} s")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figures = {"presses": presses, "costs": costs, "full_step_s": full_step, "builds_s": builds}
    args.out.write_text(json.dumps(figures, indent=1))
    print(f"wrote {args.out}")


def press_table(system: fem.System, plates: dict[int, ReducedPlate]) -> list[dict[str, object]]:
    """Force against depth, full, reduced and linear, for every tool and place."""
    some = next(iter(plates.values()))
    rows = []
    for place, at in PLACES.items():
        for kind in KINDS:
            tools = [[Tool(kind, at, depth, RADIUS)] for depth in DEPTHS]
            points = [tool_points(t, some.coordinates, some.movable, 64) for t in tools]
            began = time.perf_counter()
            full = press_nonlinear(system, points[0].coordinates, [p.surface for p in points])
            spent = time.perf_counter() - began
            linear = linear_press(system, points)
            reduced: dict[int, list[float]] = {}
            for count, plate in plates.items():
                start, forces = None, []
                for row in points:
                    solved = press_reduced(plate, row.indices, row.surface, start=start)
                    start = solved.q
                    forces.append(float(solved.forces.sum()))
                reduced[count] = forces
            rows.append({
                "place": place, "kind": kind, "depths_m": list(DEPTHS),
                "full_n": [p.force for p in full], "linear_mesh_n": linear,
                "reduced_n": reduced, "full_seconds": spent,
            })  # fmt: skip
            print(f"\n{kind} at the {place} (full plate: {spent:.0f} s for {len(DEPTHS)} depths)")
            header = " | ".join(f"{c} modes" for c in plates)
            print(f"| depth (mm) | full (N) | linear (N) | {header} |")
            print("| --- " * (3 + len(plates)) + "|")
            for i, depth in enumerate(DEPTHS):
                errors = " | ".join(f"{reduced[c][i] / full[i].force - 1:+.2%}" for c in plates)
                print(f"| {depth * 1e3:.0f} | {full[i].force:.4f} | {linear[i]:.4f} | {errors} |")
    return rows


def linear_press(system: fem.System, rows: list[ToolPoints]) -> list[float]:
    """The linear plate's force with the same lattice points held (the obstacle problem on
    K, ``fem.contact.solve_obstacle``): what the linear engines converge to."""
    g = sp.csr_matrix(sampler(system, rows[0].coordinates) @ system.transform)
    zero = np.zeros(system.free)
    return [float(solve_obstacle(system.reduced_stiffness, g, zero, row.surface)[1].sum())
            for row in rows]  # fmt: skip


def cost_table(
    scene: object, tissue: object, plates: dict[int, ReducedPlate]
) -> dict[str, dict[str, float]]:
    """Step cost (us) of a slow sphere press, in-process, per engine."""
    costs = {}
    print("\n| engine | step p50 (us) | p99 (us) | max (us) |")
    print("| --- | --- | --- | --- |")
    for count, plate in plates.items():
        engine = NonlinearPlateEngine(tissue, (20, 20), 1e-3, modes=count, plate=plate)  # type: ignore[arg-type]
        costs[f"reduced, {count} modes"] = _press_cost(engine)
    linear = build_scene_engine(load_scene("skin-patch"), tissue_parts(load_scene("skin-patch"))[0])
    costs["linear modal (skin-patch, 100 modes)"] = _press_cost(linear)
    for name, figures in costs.items():
        print(f"| {name} | {figures['p50']:.0f} | {figures['p99']:.0f} | {figures['max']:.0f} |")
    return costs


def _press_cost(engine: object, steps: int = 3000) -> dict[str, float]:
    state = engine.start().state  # type: ignore[attr-defined]
    times = np.empty(steps)
    for k in range(steps):
        tool = Tool("sphere", PLACES["centre"], DEPTHS[-1] * (k + 1) / steps, RADIUS)
        began = time.perf_counter()
        state = engine.step(state, tools=[tool], frame=False).state  # type: ignore[attr-defined]
        times[k] = time.perf_counter() - began
    us = times[100:] * 1e6
    return {"p50": float(np.percentile(us, 50)), "p99": float(np.percentile(us, 99)),
            "max": float(us.max())}  # fmt: skip


def full_step_cost(system: fem.System) -> float:
    load = fem.point_load(system, -1.0, PLACES["centre"])
    began = time.perf_counter()
    step_nonlinear(system, load, 1e-3, 3)
    return (time.perf_counter() - began) / 3


if __name__ == "__main__":
    main()
