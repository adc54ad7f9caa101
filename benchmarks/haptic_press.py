"""A slow press against the tissue's own physics (docs/HAPTICS.md, "Limits").

    python benchmarks/haptic_press.py

poke.py's ramp (1e-3 deep over 0.2 s, then held) on `membrane-live` under its soft tip, and
1 mm at 5 mm/s on `skin-patch` under a point tip, in process at the scene's dt with a step
every 1 ms tick: the force on a rigid tip following the device exactly (the engine's
position-driven probe: the tissue's physics), and the force through the default coupling
(every tick a full step: the haptic benchmark's reference, ``haptics.multirate``), each as a
ratio to the static force at the tick's depth (rigid: depth / c_static; coupled:
depth / (1.2 c_static)), the largest and smallest per window of ticks.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from haptics import multirate  # benchmarks/haptics.py, beside this script

from membrane_models.live import Probe
from membrane_server.scene import load_scene
from membrane_server.served import ServedScene

CASES = {"membrane-live": ((0.5, 0.5), 0.05), "skin-patch": ((0.025, 0.025), 0.0)}
WINDOWS = [(0, 5), (5, 10), (10, 20), (20, 50), (50, 100), (100, 200), (200, 1000)]
PERIOD = 1e-3


def press(scene: str, ticks: int = 1000) -> dict[str, np.ndarray | float]:
    at, radius = CASES[scene]
    engine = ServedScene.load(load_scene(scene)).live
    assert engine is not None, f"{scene} is not a live scene"
    depth = np.minimum(np.arange(1, ticks + 1) * PERIOD / 0.2, 1.0) * 1e-3
    state, rigid = engine.start().state, np.zeros(ticks)
    for n in range(ticks):
        out = engine.step(state, [], [Probe(at, float(depth[n]), radius)], frame=False)
        state, rigid[n] = out.state, out.probes[0].force
    static = out.probes[0].static_compliance
    coupled = multirate(engine, 1.0 / PERIOD, np.full(ticks, at[0]), depth, at[1], radius)
    return {
        "depth": depth,
        "rigid": rigid / (depth / static),
        "coupled": coupled / (depth / (1.2 * static)),
        "static": static,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.parse_args(argv)
    print("| scene | ticks (ms) | rigid tip / static, max (min) | coupled / static, max (min) |")
    print("| --- | --- | --- | --- |")
    for scene in CASES:
        result = press(scene)
        rigid, coupled = result["rigid"], result["coupled"]
        assert isinstance(rigid, np.ndarray) and isinstance(coupled, np.ndarray)
        for a, b in WINDOWS:
            r, c = rigid[a:b], coupled[a:b]
            print(
                f"| {scene} | {a}-{b} | {r.max():.2f} ({r.min():.2f}) "
                f"| {c.max():.2f} ({c.min():.2f}) |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
