"""The skin patch at large deflection: the reduced von Karman plate against the full one, and
what each way of answering costs (docs/NONLINEAR.md, "The trade-off").

    python benchmarks/nonlinear_tradeoff.py [--modes 8,12,16,20,30] [--out runs/nonlinear.json]
    python benchmarks/nonlinear_tradeoff.py --modes 20 --costs-only --repeat 3   # step cost only

On `skin-patch-nonlinear`'s mesh (the study's 50 mm clamped patch, 2.5 mm elements, edges held
in their plane) and lattice (20 x 20):

1. Static presses to 6 mm (2 h) of a flat punch and of a sphere, both 5 mm in radius, at the
   centre and off it at (19, 31) mm: the full plate (``fem.nonlinear_press``: Newton with the
   tool's lattice points constrained, on every DOF) against the reduced plate at each mode
   count (``fem.reduced_dynamics.press_reduced``, the same points), the engine's basis (20
   modes and the tool's adapted vector, ``fem.adapted_basis``, at the tool's centre rounded
   to the engine's grid) and the linear plate (the same points held on the mesh: what the
   linear engines converge to).
2. The cost of a step at 1 kHz, in-process: the reduced engine during a slow press of the
   sphere to 6 mm (3,000 steps, a tool per step, no frame) without and with the adapted
   vector (its worker started first, as a session's start does; the vector built during the
   press and stepped onto once built), the 20 modes on the numpy path alone (no compiled
   step: ``fem.reduced_kernel``), `skin-patch`'s linear engine under the same press,
   and one Newmark + Newton step of the full plate (``fem.nonlinear_transient``).
3. What an adapted vector costs to build: incrementally (``Adaptation.adapted``, off the
   step) against a whole ``reduce_plate`` with the same static point.
4. With ``--builds-beside``: the 20-mode step's cost (the modes alone) while adapted bases
   are built beside it for 3 s, side by side: nothing beside, builds in a thread of the same
   process, builds in a spawned process as the engine's worker (niced, BLAS on one thread).

The modes are built from no load and the adapted vector from a unit point force: the
validation presses differ from anything used to build either. Prints markdown tables and
writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from threadpoolctl import threadpool_limits

from membrane_models import fem
from membrane_models.fem.adapted_basis import Adaptation
from membrane_models.fem.basis_follower import WORKER_NICENESS
from membrane_models.fem.contact import solve_obstacle
from membrane_models.fem.nonlinear_engine import ADAPT_SPACING, DEFAULT_MODES, NonlinearPlateEngine
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
    parser.add_argument("--rate", type=float, default=0.0,
                        help="the cost table's presses paced at this many steps a second "
                             "(default: back to back)")  # fmt: skip
    parser.add_argument("--spin", action="store_true",
                        help="with --rate: wait polling the clock, not asleep")  # fmt: skip
    parser.add_argument(
        "--builds-beside",
        action="store_true",
        help="the step's cost beside builds in a thread and a process (part 4)",
    )
    args = parser.parse_args()
    counts = [int(c) for c in args.modes.split(",")]
    scene = load_scene("skin-patch-nonlinear")
    tissue, _, _ = tissue_parts(scene)
    system = fem.assemble(tissue.domain, tissue.model, tissue.supports, tissue.element)
    print(f"mesh: {system.dofs} plate DOFs, lattice {scene.lattice.shape}", flush=True)
    plates: dict[int, ReducedPlate] = {}
    builds: dict[int | str, float] = {}
    for count in counts:
        began = time.perf_counter()
        plates[count] = reduce_plate(system, count, (20, 20), "held")
        builds[count] = time.perf_counter() - began
        print(f"reduced plate, {count} modes: built in {builds[count]:.1f} s", flush=True)
    if args.costs_only:
        for _ in range(args.repeat):
            cost_table(scene, tissue, plates, args.rate, args.spin)
        return
    if args.builds_beside:
        for _ in range(args.repeat):
            builds_beside(tissue, plates[DEFAULT_MODES])
        return
    adaptation = None
    if DEFAULT_MODES in plates:
        began = time.perf_counter()
        adaptation = Adaptation.of(system, plates[DEFAULT_MODES], "held")
        builds["adaptation"] = time.perf_counter() - began
        print(f"adaptation (the system's factors, the modes' slopes): {builds['adaptation']:.1f} s")
    presses = press_table(system, plates, adaptation)
    costs = cost_table(scene, tissue, plates)
    full_step = full_step_cost(system)
    print(f"\nfull plate, one Newmark + Newton step at 1 ms: {full_step:.2f} s")
    if adaptation is not None:
        builds.update(adapted_costs(system, adaptation))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figures = {"presses": presses, "costs": costs, "full_step_s": full_step, "builds_s": builds}
    args.out.write_text(json.dumps(figures, indent=1))
    print(f"wrote {args.out}")


def press_table(
    system: fem.System, plates: dict[int, ReducedPlate], adaptation: Adaptation | None
) -> list[dict[str, object]]:
    """Force against depth, full, reduced and linear, for every tool and place."""
    some = next(iter(plates.values()))
    adapted_name = f"{DEFAULT_MODES} + adapted"
    rows = []
    for place, at in PLACES.items():
        for kind in KINDS:
            tools = [[Tool(kind, at, depth, RADIUS)] for depth in DEPTHS]
            points = [tool_points(t, some.coordinates, some.movable, 64) for t in tools]
            began = time.perf_counter()
            full = press_nonlinear(system, points[0].coordinates, [p.surface for p in points])
            spent = time.perf_counter() - began
            linear = linear_press(system, points)
            bases: dict[int | str, ReducedPlate] = {c: p for c, p in plates.items()}
            if adaptation is not None:
                rounded = [round(c / ADAPT_SPACING) * ADAPT_SPACING for c in at]
                bases[adapted_name] = adaptation.adapted([(rounded[0], rounded[1])]).plate
            reduced: dict[int | str, list[float]] = {}
            for count, plate in bases.items():
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
            header = " | ".join(f"{c} modes" if isinstance(c, int) else str(c) for c in bases)
            print(f"| depth (mm) | full (N) | linear (N) | {header} |")
            print("| --- " * (3 + len(bases)) + "|")
            for i, depth in enumerate(DEPTHS):
                errors = " | ".join(f"{reduced[c][i] / full[i].force - 1:+.2%}" for c in bases)
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
    scene: object,
    tissue: object,
    plates: dict[int, ReducedPlate],
    rate: float = 0.0,
    spin: bool = False,
) -> dict[str, dict[str, float]]:
    """Step cost (us) of a slow sphere press, in-process, per engine (``rate``: as
    ``_press_cost``'s)."""
    costs = {}
    print("\n| engine | step p50 (us) | p99 (us) | max (us) |")
    print("| --- | --- | --- | --- |")
    for count, plate in plates.items():
        engine = NonlinearPlateEngine(tissue, (20, 20), 1e-3, modes=count, plate=plate,  # type: ignore[arg-type]
                                      adapted=False)  # fmt: skip
        pressed = functools.partial(_press_cost, rate=rate, spin=spin)
        costs[f"reduced, {count} modes"] = pressed(engine)
        if count == DEFAULT_MODES:
            engine = NonlinearPlateEngine(tissue, (20, 20), 1e-3, modes=count, plate=plate,  # type: ignore[arg-type]
                                          adapted=False, compiled=False)  # fmt: skip
            costs[f"reduced, {count} modes, numpy path"] = pressed(engine)
            engine = NonlinearPlateEngine(tissue, (20, 20), 1e-3, modes=count, plate=plate)  # type: ignore[arg-type]
            costs[f"reduced, {count} modes + adapted"] = pressed(engine)
            engine.close()
    linear = build_scene_engine(load_scene("skin-patch"), tissue_parts(load_scene("skin-patch"))[0])
    costs["linear modal (skin-patch, 100 modes)"] = _press_cost(linear, rate=rate, spin=spin)
    for name, figures in costs.items():
        print(f"| {name} | {figures['p50']:.0f} | {figures['p99']:.0f} | {figures['max']:.0f} |")
    return costs


def _press_cost(
    engine: object, steps: int = 3000, rate: float = 0.0, spin: bool = False
) -> dict[str, float]:
    """The press's step costs; ``rate`` > 0: a step every 1 / rate s, as a haptic loop's, the
    time between steps slept (``spin``: spent polling the clock, as ``membrane serve
    --spin-us`` does), else back to back."""
    state = engine.start().state  # type: ignore[attr-defined]
    follower = getattr(engine, "follower", None)
    if follower is not None:
        follower.wait()  # the worker ready, as a session's start makes it before a press
    times = np.empty(steps)
    switched = -1
    origin = time.perf_counter()
    for k in range(steps):
        tool = Tool("sphere", PLACES["centre"], DEPTHS[-1] * (k + 1) / steps, RADIUS)
        if rate > 0.0:
            due = origin + k / rate
            if not spin:
                time.sleep(max(0.0, due - time.perf_counter()))
            while time.perf_counter() < due:
                pass
        began = time.perf_counter()
        new = engine.step(state, tools=[tool], frame=False).state  # type: ignore[attr-defined]
        times[k] = time.perf_counter() - began
        if getattr(new, "adapted", None) is not getattr(state, "adapted", None):
            switched = k
        state = new
    us = times[100:] * 1e6
    figures = {"p50": float(np.percentile(us, 50)), "p99": float(np.percentile(us, 99)),
               "max": float(us.max())}  # fmt: skip
    if switched >= 0:
        figures["switch_step"] = float(switched)
        figures["switch_us"] = float(times[switched] * 1e6)
        print(f"(the adapted vector stepped onto at step {switched}, "
              f"{times[switched] * 1e6:.0f} us that step)")  # fmt: skip
    return figures


def adapted_costs(system: fem.System, adaptation: Adaptation, repeat: int = 5) -> dict[str, float]:
    """Seconds to build one place's adapted basis (the median of ``repeat`` places near the
    centre) against a whole reduced plate with the same static point, both on one BLAS
    thread."""
    places = [(0.025 + 0.0005 * k, 0.025) for k in range(repeat)]
    spent = []
    # BLAS on one thread, as in the engine's worker (a threaded BLAS on shared cores took the
    # same build from 0.27 to 1.5 s here)
    with threadpool_limits(limits=1, user_api="blas"):
        for at in places:
            began = time.perf_counter()
            adaptation.adapted([at])
            spent.append(time.perf_counter() - began)
        began = time.perf_counter()
        reduce_plate(system, DEFAULT_MODES, (20, 20), "held", static_points=[places[0]])
        whole = time.perf_counter() - began
    print(f"adapted vector: {np.median(spent):.2f} s a place (median of {repeat}), "
          f"a whole reduce_plate with it {whole:.2f} s")  # fmt: skip
    return {"adapted_place": float(np.median(spent)), "whole_with_static": whole}


def builds_beside(tissue: object, plate: ReducedPlate, seconds: float = 3.0) -> None:
    """The press's step cost with nothing beside it, with adapted bases built in a thread
    and in a worker process (``basis_follower``'s) meanwhile."""
    engine = NonlinearPlateEngine(tissue, (20, 20), 1e-3, plate=plate, adapted=False)  # type: ignore[arg-type]
    domain = tissue.domain  # type: ignore[attr-defined]
    parts = (domain.mesh, dict(domain.parts), dict(domain.curves))  # its maps do not pickle
    model = (tissue.model, tissue.supports, tissue.element)  # type: ignore[attr-defined]
    make = functools.partial(_adaptation_of, parts, model, plate)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, context, _worker_start, (make,)) as pool:
        pool.submit(_build_for, 0.0).result()  # the worker's adaptation made
        _worker_start(make, nice=False)  # the thread's adaptation, in this process
        print("\n| beside the steps | step p50 (us) | p99 (us) | max (us) | places built |")
        print("| --- | --- | --- | --- | --- |")
        figures = _press_cost(engine)
        print(f"| nothing | {figures['p50']:.0f} | {figures['p99']:.0f} | {figures['max']:.0f} | |")
        built: list[int] = []
        thread = threading.Thread(target=lambda: built.append(_build_for(seconds)))
        thread.start()
        figures = _press_cost(engine)
        thread.join()
        print(f"| a thread | {figures['p50']:.0f} | {figures['p99']:.0f} | "
              f"{figures['max']:.0f} | {built[0]} |")  # fmt: skip
        future = pool.submit(_build_for, seconds)
        figures = _press_cost(engine)
        print(f"| a process | {figures['p50']:.0f} | {figures['p99']:.0f} | "
              f"{figures['max']:.0f} | {future.result()} |")  # fmt: skip


_made: list[Adaptation] = []


def _adaptation_of(
    parts: tuple[Any, ...], model: tuple[Any, ...], plate: ReducedPlate
) -> Adaptation:
    system = fem.assemble(fem.Domain(*parts), *model)
    return Adaptation.of(system, plate, "held")


def _worker_start(make: functools.partial[Adaptation], nice: bool = True) -> None:
    """BLAS on one thread in either process (the steps' too: as ``membrane serve`` runs)."""
    threadpool_limits(limits=1, user_api="blas")
    if nice:
        os.nice(WORKER_NICENESS)
    if not _made:
        _made.append(make())


def _build_for(seconds: float) -> int:
    """Adapted bases at places along x for ``seconds``: how many were built."""
    end, count = time.perf_counter() + seconds, 0
    while time.perf_counter() < end:
        _made[0].adapted([(0.02 + 0.00025 * count, 0.025)])
        count += 1
    return count


def full_step_cost(system: fem.System) -> float:
    load = fem.point_load(system, -1.0, PLACES["centre"])
    began = time.perf_counter()
    step_nonlinear(system, load, 1e-3, 3)
    return (time.perf_counter() - began) / 3


if __name__ == "__main__":
    main()
