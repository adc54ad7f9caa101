"""`skin-patch`'s live step in process, as its server runs it, beside `membrane-live`'s.

Both scenes are loaded as `membrane serve` loads them (skin-patch from its shipped mode cache:
100 FEM plate modes, point forces, the static correction). One point probe presses 0.1 mm at the
patch's centre (moving by up to 6 um, so that nothing is reused), the haptic loop's
step: no frame (`--every 0`) or a frame every N steps. `membrane-live`'s probe (the soft tip,
radius 0.05, depth 1e-4 at the same relative place) is the baseline, timed in alternating blocks
so that load on the machine weighs on both alike. Prints p50, p99 and p99.9 (us) and the ratios.

    python benchmarks/skin_patch_step.py [--steps 20000] [--every 10]
"""

from __future__ import annotations

import argparse
import gc
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from membrane_models.live import Probe
from membrane_server.scene import load_scene
from membrane_server.served import ServedScene

Probes = Callable[[int], list[Probe]]


def _engines() -> dict[str, tuple[Any, Probes]]:
    skin = ServedScene.load(load_scene("skin-patch")).live
    live = ServedScene.load(load_scene("membrane-live")).live
    return {
        "skin-patch": (skin, lambda k: [Probe((0.025 + 1e-6 * (k % 7), 0.025), 1e-4, 0.0)]),
        "membrane-live": (live, lambda k: [Probe((0.5 + 2e-5 * (k % 7), 0.5), 1e-4, 0.05)]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20_000, help="steps per scene")
    parser.add_argument("--block", type=int, default=500, help="steps per alternating block")
    parser.add_argument("--every", type=int, default=0, help="a frame every N steps (0: none)")
    args = parser.parse_args()
    engines = _engines()
    times: dict[str, list[float]] = {name: [] for name in engines}
    touching = dict.fromkeys(engines, 0)
    states = {name: engine.start().state for name, (engine, _) in engines.items()}
    gc.collect()
    gc.freeze()  # the server freezes its heap after load too (membrane_server.heap)
    clock = time.perf_counter
    for block in range(0, args.steps, args.block):
        for name, (engine, probes) in engines.items():
            state, spent = states[name], times[name]
            for k in range(block, block + args.block):
                frame = args.every > 0 and k % args.every == 0
                begin = clock()
                result = engine.step(state, (), probes(k), frame=frame)
                spent.append(clock() - begin)
                state = result.state
                touching[name] += result.probes[0].in_contact
            states[name] = state
    figures = {name: np.percentile(np.array(t) * 1e6, [50, 99, 99.9]) for name, t in times.items()}
    frames = "no frame" if args.every <= 0 else f"a frame every {args.every} steps"
    print(f"{args.steps} steps per scene, one probe, {frames}")
    print("| scene | modes | steps in contact | p50 (us) | p99 (us) | p99.9 (us) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, (engine, _) in engines.items():
        p50, p99, p999 = figures[name]
        share = f"{touching[name] / args.steps:.0%}"
        print(f"| {name} | {engine.modes.count} | {share} | {p50:.1f} | {p99:.1f} | {p999:.1f} |")
    ratio = figures["skin-patch"] / figures["membrane-live"]
    print(f"skin-patch / membrane-live: p50 {ratio[0]:.2f}x, p99 {ratio[1]:.2f}x")


if __name__ == "__main__":
    main()
