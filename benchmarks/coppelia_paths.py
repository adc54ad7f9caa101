"""Time per simulation step of the two ways to move the lattice, against the CoppeliaSim stand-in.

Starts the stand-in (``python -m membrane_coppelia.standin``) and a membrane server
(``membrane serve``) as separate processes on loopback, then drives the scene's lattice (400
spheres for the built-in ``membrane`` scene) for ``--steps`` steps with each move path:

- ``batched``: one ``sim.callScriptFunction`` per step moves every sphere;
- ``per-sphere``: one ``sim.setObjectPosition`` per sphere per step.

The baseline, measured in the same run, is one bare remote API round trip
(``sim.getSimulationTime``). Reported: p50/p99 of each part of a step (query, move, step, total)
and of the simulator side (total minus the query), and ratios to the baseline and between the
paths.

What this measures: round trips to a stand-in and our own overhead (encoding, the client, the
loop). It says nothing of CoppeliaSim's own cost: a real CoppeliaSim adds its Lua calls,
physics and rendering, and the remote API server handles requests between simulation passes.

    .venv/bin/python benchmarks/coppelia_paths.py --steps 100 --json out/coppelia_paths.json
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from membrane_client import Client
from membrane_coppelia.batch_script import BATCH_FUNCTION, BATCH_SCRIPT
from membrane_coppelia.film import run_film
from membrane_coppelia.lattice import BATCHED, PER_SPHERE, SphereLattice
from membrane_coppelia.link import SimulatorLink, connect_simulator
from membrane_coppelia.standin import SIM_CONSTANTS, FakeScene

log = logging.getLogger("coppelia_paths")


@contextmanager
def announced_process(command: list[str], prefix: str) -> Iterator[str]:
    """Run ``command``; yield the tcp:// address its first stdout line starting with ``prefix``
    announces."""
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        while not line.startswith(prefix):
            if not line:
                raise RuntimeError(f"{' '.join(command)} exited before announcing its address")
            line = process.stdout.readline()
        yield next(word for word in line.split() if word.startswith("tcp://"))
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def round_trip_baseline(link: SimulatorLink, count: int) -> list[float]:
    """Durations of ``count`` bare remote API calls (``sim.getSimulationTime``)."""
    durations = []
    for _ in range(count):
        start = time.perf_counter()
        link.sim.getSimulationTime()
        durations.append(time.perf_counter() - start)
    return durations


def standin_batch_apply(spheres: int, repeats: int) -> list[float]:
    """Durations of the stand-in's own work for one batched call (in process, no sockets).

    Part of the batched path's figures, playing the part of CoppeliaSim's Lua loop: subtract it
    to see the transport and our overhead alone.
    """
    scene = FakeScene()
    parent = scene.create_dummy(0.05)
    handles = []
    for _ in range(spheres):
        handle = scene.create_primitive_shape(SIM_CONSTANTS["primitiveshape_spheroid"], [0.05] * 3)
        scene.set_parent(handle, parent, True)
        handles.append(handle)
    script = scene.create_script(SIM_CONSTANTS["scripttype_customization"], BATCH_SCRIPT)
    scene.init_script(script)
    xyz = np.random.default_rng(0).random(3 * spheres).tolist()
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        scene.call_script_function(BATCH_FUNCTION, script, handles, xyz, parent)
        durations.append(time.perf_counter() - start)
    return durations


def percentiles(values: Sequence[float]) -> dict[str, float]:
    """p50 and p99 in milliseconds."""
    return {
        "p50_ms": float(np.percentile(values, 50)) * 1e3,
        "p99_ms": float(np.percentile(values, 99)) * 1e3,
    }


def measure_path(link: SimulatorLink, server: str, batched: bool, steps: int) -> dict[str, Any]:
    """Build the lattice, run ``steps`` steps with one move path, remove it; per-part figures."""
    with (
        Client(server, timeout=5.0) as client,
        SphereLattice(
            link.sim, client, batched=batched, address=link.address, timeout=link.timeout
        ) as lattice,
    ):
        lattice.build()
        result = run_film(lattice, max_steps=steps)
    timings = result.timings
    simulator_side = np.array(timings.total) - np.array(timings.query)
    return {
        "path": result.path,
        "spheres": result.spheres,
        "steps": result.steps,
        "query": percentiles(timings.query),
        "move": percentiles(timings.move),
        "step": percentiles(timings.step),
        "total": percentiles(timings.total),
        "simulator_side": percentiles(simulator_side.tolist()),
    }


def report(results: dict[str, Any]) -> str:
    """A small text table with the ratios."""
    baseline = results["baseline_round_trip"]["p50_ms"]
    lines = [
        f"stand-in round trip (baseline): p50 {baseline:.3f} ms, "
        f"p99 {results['baseline_round_trip']['p99_ms']:.3f} ms",
        f"{'path':<11} {'spheres':>7} {'move p50/p99 ms':>18} {'sim side p50/p99 ms':>21} "
        f"{'total p50/p99 ms':>18} {'sim side / RT':>13}",
    ]
    for path in (BATCHED, PER_SPHERE):
        r = results[path]
        side = r["simulator_side"]
        lines.append(
            f"{r['path']:<11} {r['spheres']:>7} "
            f"{r['move']['p50_ms']:>8.3f}/{r['move']['p99_ms']:<9.3f} "
            f"{side['p50_ms']:>10.3f}/{side['p99_ms']:<10.3f} "
            f"{r['total']['p50_ms']:>8.3f}/{r['total']['p99_ms']:<9.3f} "
            f"{side['p50_ms'] / baseline:>13.1f}"
        )
    apply = results["standin_batch_apply"]
    lines.append(
        f"stand-in's own work in one batched call: p50 {apply['p50_ms']:.3f} ms, "
        f"p99 {apply['p99_ms']:.3f} ms"
    )
    lines.append(
        f"per-sphere / batched, simulator side p50: {results['speedup_simulator_side_p50']:.1f}x"
    )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="membrane", help="built-in scene (default membrane)")
    parser.add_argument("--steps", type=int, default=100, help="steps per path (default 100)")
    parser.add_argument("--round-trips", type=int, default=2000, help="baseline calls")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    standin = [sys.executable, "-m", "membrane_coppelia.standin", "--port", "0"]
    serve = [sys.executable, "-m", "membrane_cli", "serve", "--scene", args.scene]
    serve += ["--bind", "tcp://127.0.0.1:*"]
    with (
        announced_process(standin, "coppelia stand-in listening") as sim_address,
        announced_process(serve, "membrane serve: listening") as server,
    ):
        port = int(sim_address.rsplit(":", 1)[1])
        link = connect_simulator("127.0.0.1", port, timeout=10.0)
        try:
            log.info("baseline: %d bare round trips", args.round_trips)
            results: dict[str, Any] = {
                "scene": args.scene,
                "baseline_round_trip": percentiles(round_trip_baseline(link, args.round_trips)),
            }
            for batched in (True, False):
                log.info("%s: %d steps", BATCHED if batched else PER_SPHERE, args.steps)
                figures = measure_path(link, server, batched, args.steps)
                results[figures["path"]] = figures
        finally:
            link.close()
    spheres = results[BATCHED]["spheres"]
    results["standin_batch_apply"] = percentiles(standin_batch_apply(spheres, args.steps))
    results["speedup_simulator_side_p50"] = (
        results[PER_SPHERE]["simulator_side"]["p50_ms"]
        / results[BATCHED]["simulator_side"]["p50_ms"]
    )
    print(report(results))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
