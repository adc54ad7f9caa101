"""A slow press to 6 mm on `skin-patch-nonlinear` over the wire, beside `skin-patch` (the linear
plate) and the full nonlinear plate's static points (docs/NONLINEAR.md, "Pressed over the wire").

    python benchmarks/nonlinear_press_wire.py [--tool cylinder|sphere] [--plot FILE.png]

Serves both scenes from one in-process server on 127.0.0.1 (a random port; or --connect to a
running `membrane serve` holding both), opens a live session on each and presses a rigid tool
of 5 mm radius at the patch's centre from the rest surface to 6 mm (2 h) over 3 s at 1 kHz, a
step per ms, then holds it 0.5 s. Prints the force at each millimetre (the slow press's, and the
hold's at 6 mm) beside the full von Karman plate pressed statically at the same lattice points
(``fem.nonlinear_press``, every DOF), and plots force against depth.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from membrane_client import Client, Tool
from membrane_models import fem
from membrane_models.fem.contact import solve_obstacle
from membrane_models.fem.nonlinear_press import press_nonlinear
from membrane_models.fem.reduced_plate import ReducedPlate
from membrane_models.fem.sampling import sampler
from membrane_models.live.interface import Tool as EngineTool
from membrane_models.live.tools import tool_points
from membrane_server.served import ServedScene
from membrane_server.server import Server
from membrane_server.tissue_scene import tissue_parts

CENTRE, RADIUS, DEPTH = (0.025, 0.025), 0.005, 0.006
PRESS_STEPS, HOLD_STEPS = 3000, 500
MARKS = (0.001, 0.002, 0.003, 0.004, 0.005, 0.006)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tool", choices=("cylinder", "sphere"), default="cylinder")
    parser.add_argument("--connect", help="a running server holding both scenes")
    parser.add_argument("--plot", type=Path, default=Path("docs/nonlinear-press.png"))
    args = parser.parse_args()
    scenes = [ServedScene.load("skin-patch"), ServedScene.load("skin-patch-nonlinear")]
    server = None
    address = args.connect
    if address is None:
        server = Server(scenes, bind="tcp://127.0.0.1:*")
        server.start()
        address = server.address
    try:
        curves = {name: _press(address, name, args.tool) for name in
                  ("skin-patch", "skin-patch-nonlinear")}  # fmt: skip
    finally:
        if server is not None:
            server.stop()
    full = _full_points(scenes[1], args.tool)
    _print(curves, full, args.tool)
    _plot(curves, full, args.tool, args.plot)


def _press(address: str, scene: str, kind: str) -> tuple[np.ndarray, np.ndarray, float]:
    """(depths, forces) of the slow press, and the force after the hold at 6 mm."""
    depths, forces = np.empty(PRESS_STEPS), np.empty(PRESS_STEPS)
    began = time.perf_counter()
    with Client(address, timeout=30.0) as client, client.session(scene) as session:
        for k in range(PRESS_STEPS):
            depths[k] = DEPTH * (k + 1) / PRESS_STEPS
            frame = session.step(tools=[Tool(kind, CENTRE, float(depths[k]), RADIUS)])
            forces[k] = frame.tools[0].force
        for _ in range(HOLD_STEPS):
            frame = session.step(tools=[Tool(kind, CENTRE, DEPTH, RADIUS)])
    print(f"{scene}: {PRESS_STEPS + HOLD_STEPS} steps over the wire in "
          f"{time.perf_counter() - began:.1f} s", flush=True)  # fmt: skip
    return depths, forces, float(frame.tools[0].force)


def _full_points(scene: ServedScene, kind: str) -> tuple[list[float], list[float]]:
    """The full von Karman plate pressed statically at the same lattice points, and the full
    linear plate with the same points held (``fem.contact.solve_obstacle``)."""
    engine = scene.live
    plate: ReducedPlate = engine.plate  # type: ignore[union-attr]
    tissue, _, _ = tissue_parts(scene.scene)
    system = fem.assemble(tissue.domain, tissue.model, tissue.supports, tissue.element)
    tools = [[EngineTool(kind, CENTRE, depth, RADIUS)] for depth in MARKS]
    rows = [tool_points(t, plate.coordinates, plate.movable, 64) for t in tools]
    began = time.perf_counter()
    nonlinear = press_nonlinear(system, rows[0].coordinates, [r.surface for r in rows])
    g = sp.csr_matrix(sampler(system, rows[0].coordinates) @ system.transform)
    zero = np.zeros(system.free)
    linear = [float(solve_obstacle(system.reduced_stiffness, g, zero, r.surface)[1].sum())
              for r in rows]  # fmt: skip
    print(f"full plate: {len(MARKS)} depths in {time.perf_counter() - began:.0f} s", flush=True)
    return [p.force for p in nonlinear], linear


def _print(
    curves: dict[str, tuple[np.ndarray, np.ndarray, float]],
    full: tuple[list[float], list[float]],
    kind: str,
) -> None:
    print(f"\n{kind} of {RADIUS * 1e3:g} mm radius at the centre, pressed over 3 s (forces in N)")
    print("| depth (mm) | skin-patch (linear) | skin-patch-nonlinear | full plate, nonlinear | "
          "reduced / full | full plate, linear |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    for mark, full_force, linear_force in zip(MARKS, *full, strict=True):
        index = round(mark / DEPTH * PRESS_STEPS) - 1
        ours = curves["skin-patch-nonlinear"][1][index]
        flat = curves["skin-patch"][1][index]
        print(f"| {mark * 1e3:.0f} | {flat:.4f} | {ours:.4f} | {full_force:.4f} | "
              f"{ours / full_force - 1:+.2%} | {linear_force:.4f} |")  # fmt: skip
    held = curves["skin-patch-nonlinear"][2]
    print(f"| 6, held 0.5 s | {curves['skin-patch'][2]:.4f} | {held:.4f} | {full[0][-1]:.4f} | "
          f"{held / full[0][-1] - 1:+.2%} | {full[1][-1]:.4f} |")  # fmt: skip


def _plot(
    curves: dict[str, tuple[np.ndarray, np.ndarray, float]],
    full: tuple[list[float], list[float]],
    kind: str,
    path: Path,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    for name, label in (("skin-patch", "skin-patch (linear), served"),
                        ("skin-patch-nonlinear", "skin-patch-nonlinear, served")):  # fmt: skip
        depths, forces, _ = curves[name]
        axes.plot(depths * 1e3, forces, label=label)
    marks = np.array(MARKS) * 1e3
    axes.plot(marks, full[0], "ko", label="full von Karman plate (static)")
    axes.plot(marks, full[1], "kx", label="full linear plate (static)")
    axes.set_xlabel("depth (mm)")
    axes.set_ylabel("tool force (N)")
    axes.set_title(f"{kind}, 5 mm radius, at the centre of the 50 mm clamped patch (h = 3 mm)")
    axes.title.set_fontsize(9)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
