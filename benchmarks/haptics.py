"""The haptic loop's numbers (docs/HAPTICS.md, docs/BENCHMARKS.md "Haptics").

    python benchmarks/haptics.py                 # 60 s per rate at 1 and 5 kHz, as documented
    python benchmarks/haptics.py --seconds 20 --rates 1000 --no-fidelity

Deadlines: against a real `membrane serve --scene skin-patch`, while a second process keeps one
core busy, the haptic loop (``membrane_client.haptics``, its network side in its own process)
and a bare loop that only sleeps to its deadlines run in alternating windows (10 s by
default), so both see the same load; per rate, each gets ``--seconds`` in all. A tick is missed
when it begins a period or more after its deadline (the loop's own rule, applied to both).

Fidelity: a scripted hand presses 1 mm into the skin patch at 10 mm/s, slides 10 mm at
20 mm/s and lifts off; its force history through the haptic loop against a served scene whose
dt is 1, 5 or 10 ms, beside the reference where every 1 ms tick is a full step of a 1 ms scene
with the same coupling (in process: the rendering's own error, without the network's). Both
are relative L2 errors over the script's ticks; "offline" runs the loop's arithmetic in process
at the variant's dt (no network), "served" is the real loop against a real server.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from membrane_client.haptics import Contact, Coupling, HapticLoop, Proxy, Tick
from membrane_client.haptics.histogram import Histogram
from membrane_client.haptics.realtime import DEFAULT_PRIORITY, make_realtime
from membrane_client.live_schema import MAX_DEPTH
from membrane_models.live import Load, Probe
from membrane_server.scene import load_scene
from membrane_server.served import ServedScene

SCENE = "skin-patch"
AT = (0.02, 0.025)  # the press starts 5 mm left of the centre and slides 10 mm right
DEPTH = 1e-3


def script(rate: float) -> tuple[np.ndarray, np.ndarray]:
    """The hand's x and depth at each tick: press at 10 mm/s, slide 10 mm at 20 mm/s, lift at
    10 mm/s, rest 0.1 s (1.3 s)."""
    period = 1.0 / rate
    t = np.arange(round(1.3 * rate)) * period
    depth = np.clip(np.minimum(t / 0.1, (1.2 - t) / 0.1), 0.0, 1.0) * DEPTH
    x = AT[0] + np.clip((t - 0.2) / 0.5, 0.0, 1.0) * 0.01
    return x, depth


def multirate(
    engine: Any,
    rate: float,
    x: np.ndarray,
    depth: np.ndarray,
    y: float = AT[1],
    radius: float = 0.0,
) -> np.ndarray:
    """The loop's arithmetic in process: a step every dt with the last force as its load, the
    ticks between rendered from the step's look-ahead (as ``haptics.network`` and ``loop``);
    the tip at (x[n], y) with a footprint of ``radius``."""
    period, coupling = 1.0 / rate, Coupling()
    per_step = max(1, round(engine.dt / period))
    state = engine.start().state
    contact, proxy, forces = Contact(0.0, math.nan), Proxy(), np.zeros(x.size)
    for n in range(x.size):
        if n % per_step == 0:  # the network side's step, with the force rendered last tick
            at = (float(x[n]), y)
            load = [Load(at, -proxy.force, radius)] if proxy.force > 0 else []
            clear = [Probe(at, -MAX_DEPTH, radius)]
            state = engine.step(state, load, clear, frame=False).state
            ahead = engine.step(state, load, clear, frame=False).probes[0]
            free = ahead.displacement + ahead.compliance * proxy.force
            contact = Contact.ahead(free, ahead.compliance, ahead.static_compliance, n)
        proxy = coupling.render(float(depth[n]), proxy, contact, period)
        forces[n] = proxy.force
    return forces


def relative_l2(forces: np.ndarray, reference: np.ndarray) -> float:
    return float(np.linalg.norm(forces - reference) / np.linalg.norm(reference))


@contextmanager
def served(scene: str) -> Iterator[str]:
    """`membrane serve --scene SCENE` on a random loopback port; its address."""
    command = [sys.executable, "-m", "membrane_cli", "serve", "--scene", scene]
    process = subprocess.Popen(
        [*command, "--bind", "tcp://127.0.0.1:*"], stdout=subprocess.PIPE, text=True
    )
    try:
        assert process.stdout is not None
        for line in process.stdout:
            if "listening on " in line:
                yield line.split("listening on ", 1)[1].split()[0]
                break
        else:
            raise RuntimeError(f"membrane serve --scene {scene} did not start")
    finally:
        process.kill()
        process.wait(10)


@contextmanager
def busy_core() -> Iterator[None]:
    """A second process keeping one core busy for the block."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait(10)


def bare_loop(rate: float, seconds: float, priority: int | None) -> dict[str, float]:
    """A thread that only sleeps to its deadlines, at the haptic loop's priority: ticks,
    misses, p99 lateness (us)."""
    result: dict[str, float] = {}
    thread = threading.Thread(target=_bare, args=(rate, seconds, priority, result))
    thread.start()
    thread.join()
    return result


def _bare(rate: float, seconds: float, priority: int | None, result: dict[str, float]) -> None:
    realtime = make_realtime(priority)
    period, late = 1.0 / rate, Histogram()  # the haptic loop's own bookkeeping
    missed, ticks = 0, 0
    start = deadline = time.monotonic()
    while deadline - start < seconds:
        now = time.monotonic()
        if now < deadline:
            time.sleep(deadline - now)
            now = time.monotonic()
        late.add(now - deadline)
        behind = int((now - deadline) / period)
        if behind:
            missed += behind
            deadline += behind * period
        ticks += 1
        deadline += period
    result.update(
        ticks=ticks,
        missed=missed,
        late_p99_us=late.percentile(99) * 1e6,
        realtime=float(realtime),
    )


def haptic_window(
    address: str, rate: float, seconds: float, priority: int | None
) -> dict[str, float]:
    """The haptic loop for ``seconds``, the hand repeating the script."""
    x, depth = script(rate)
    ticks = [0]

    def position() -> tuple[float, float, float]:
        n = ticks[0] % x.size
        return float(x[n]), AT[1], float(depth[n])

    def count(_: Tick) -> None:
        ticks[0] += 1

    loop = HapticLoop(address, SCENE, position, rate_hz=rate, render=count, priority=priority)
    with loop:
        time.sleep(seconds)
    r = loop.report()
    return {
        "ticks": r.ticks,
        "missed": r.missed,
        "late_p99_us": r.late_p99_us,
        "compute_p50_us": r.compute_p50_us,
        "compute_p99_us": r.compute_p99_us,
        "steps": r.steps,
        "skipped": r.skipped,
        "stale_ticks": r.stale_ticks,
        "realtime": float(r.realtime),
    }


def deadlines(rate: float, seconds: float, window: float, priority: int | None) -> dict[str, Any]:
    """Alternating windows of the bare and the haptic loop at ``rate``, under a busy core."""
    totals: dict[str, list[dict[str, float]]] = {"bare": [], "haptic": []}
    with served(SCENE) as address, busy_core():
        for index in range(2 * max(1, round(seconds / window))):
            kind = "bare" if index % 2 == 0 else "haptic"
            print(f"  {rate:g} Hz, window {index + 1}: {kind}", file=sys.stderr, flush=True)
            if kind == "bare":
                totals[kind].append(bare_loop(rate, window, priority))
            else:
                totals[kind].append(haptic_window(address, rate, window, priority))
    return {kind: _pooled(windows) for kind, windows in totals.items()}


def _pooled(windows: list[dict[str, float]]) -> dict[str, float]:
    summed = {k: sum(w[k] for w in windows) for k in ("ticks", "missed")}
    worst = {k: max(w[k] for w in windows) for k in windows[0] if k.endswith("_us")}
    kept = [k for k in ("steps", "skipped", "stale_ticks") if k in windows[0]]
    worst["realtime"] = min(w["realtime"] for w in windows)  # 1: every window ran SCHED_FIFO
    counts: dict[str, float] = {k: sum(w[k] for w in windows) for k in kept}
    return {**summed, **worst, **counts}


def fidelity(dts: list[float], rate: float) -> list[dict[str, float]]:
    """Offline and served relative L2 errors per scene dt (module docstring)."""
    x, depth = script(rate)
    reference = multirate(_engine(1e-3), rate, x, depth)
    rows = []
    for dt in dts:
        offline = relative_l2(multirate(_engine(dt), rate, x, depth), reference)
        with _variant(dt) as scene_file, served(str(scene_file)) as address:
            forces = _served_forces(address, scene_file.stem, rate, x, depth)
        rows.append(
            {"dt_ms": dt * 1e3, "offline": offline, "served": relative_l2(forces, reference)}
        )
    return rows


def _served_forces(
    address: str, scene: str, rate: float, x: np.ndarray, depth: np.ndarray
) -> np.ndarray:
    forces: list[float] = []

    def position() -> tuple[float, float, float]:  # the hand at the loop's tick, not wall time
        n = min(len(forces), x.size - 1)
        return float(x[n]), AT[1], float(depth[n])

    def keep(tick: Tick) -> None:
        forces.append(tick.force)

    loop = HapticLoop(address, scene, position, rate_hz=rate, render=keep)
    with loop:
        while len(forces) < x.size:
            time.sleep(0.01)
    return np.array(forces[: x.size])


def _engine(dt: float) -> Any:
    scene = load_scene(SCENE)
    return ServedScene.load(scene.model_copy(update={"dt": dt, "duration": dt})).live


@contextmanager
def _variant(dt: float) -> Iterator[Path]:
    text = (resources.files("membrane_server") / "scenes" / f"{SCENE}.toml").read_text()
    text = text.replace("\ndt = 0.001\n", f"\ndt = {dt!r}\n")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{SCENE}-dt{dt * 1e3:g}ms.toml"
        path.write_text(text)
        yield path


def _table(rows: dict[float, dict[str, Any]], fidelity_rows: list[dict[str, float]]) -> str:
    lines = [
        "| rate | loop | priority | ticks | missed | late p99 (us) | compute p50 / p99 (us) "
        "| steps / skipped |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for rate, kinds in rows.items():
        for kind, r in kinds.items():
            compute = (
                f"{r['compute_p50_us']:.0f} / {r['compute_p99_us']:.0f}" if kind == "haptic" else ""
            )
            steps = f"{r['steps']:.0f} / {r['skipped']:.0f}" if kind == "haptic" else ""
            lines.append(
                f"| {rate / 1e3:g} kHz | {kind} | {_priority(r)} | {r['ticks']:.0f} "
                f"| {r['missed']:.0f} "
                f"({100 * r['missed'] / max(r['ticks'], 1):.2f} %) | {r['late_p99_us']:.0f} | "
                f"{compute} | {steps} |"
            )
    if fidelity_rows:
        lines += ["", "| scene dt | offline rel. L2 | served rel. L2 |", "| --- | --- | --- |"]
        lines += [
            f"| {r['dt_ms']:g} ms | {r['offline']:.2e} | {r['served']:.2e} |" for r in fidelity_rows
        ]
    return "\n".join(lines)


def _priority(row: dict[str, Any]) -> str:
    return f"FIFO {DEFAULT_PRIORITY}" if row["realtime"] else "normal"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--seconds", type=float, default=60.0, help="per rate and loop (default 60)"
    )
    parser.add_argument(
        "--window", type=float, default=10.0, help="alternation window (default 10 s)"
    )
    parser.add_argument("--rates", type=float, nargs="+", default=[1000.0, 5000.0])
    parser.add_argument("--dts", type=float, nargs="+", default=[0.001, 0.005, 0.01])
    parser.add_argument("--no-fidelity", action="store_true")
    parser.add_argument(
        "--normal-priority",
        action="store_true",
        help="both loops at normal priority (default: SCHED_FIFO where granted)",
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    priority = None if args.normal_priority else DEFAULT_PRIORITY
    rows = {rate: deadlines(rate, args.seconds, args.window, priority) for rate in args.rates}
    print("  fidelity", file=sys.stderr, flush=True)
    fidelity_rows = [] if args.no_fidelity else fidelity(args.dts, 1000.0)
    if args.json:
        print(json.dumps({"deadlines": rows, "fidelity": fidelity_rows}, indent=2))
    else:
        print(_table(rows, fidelity_rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
