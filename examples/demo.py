"""The main demo: a membrane server and a simulator-like client polling it for one second.

Starts `membrane serve` on the built-in `membrane` scene (a 20 x 20 skin patch under a Gaussian
force) on a free loopback port, polls it at every time step of one simulated second (101 steps,
paced at dt like a 100 Hz simulator loop unless --fast), prints what it saw and the round-trip
latency, draws a plot when matplotlib is installed, and stops the server with SIGTERM.

    python examples/demo.py [--scene NAME] [--fast] [--plot out/demo.png]

Needs the server extra only (pip install -e '.[server,plot]'); no torch.
"""

from __future__ import annotations

import argparse
import logging
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from membrane_client import Client, Frame, SceneInfo
from membrane_client.replies import StatsReply

logger = logging.getLogger("demo")

START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0


def start_server(scene: str) -> tuple[subprocess.Popen[str], str]:
    """Start `membrane serve` on a free loopback port; returns the process and its address."""
    command = [
        sys.executable, "-m", "membrane_cli", "serve",
        "--scene", scene, "--bind", "tcp://127.0.0.1:*",
    ]  # fmt: skip
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    lines: queue.Queue[str] = queue.Queue()
    # The server prints its address on its first stdout line; read it without blocking forever.
    threading.Thread(target=lambda: lines.put(process.stdout.readline()), daemon=True).start()  # type: ignore[union-attr]
    try:
        line = lines.get(timeout=START_TIMEOUT_S)
    except queue.Empty:
        process.kill()
        raise RuntimeError(f"the server did not start within {START_TIMEOUT_S} s") from None
    if "listening on " not in line:
        process.wait(timeout=STOP_TIMEOUT_S)
        raise RuntimeError(f"the server failed to start (exit code {process.returncode})")
    return process, line.split("listening on ", 1)[1].split()[0]


def stop_server(process: subprocess.Popen[str]) -> int:
    """SIGTERM, then wait; returns the exit code (killed after STOP_TIMEOUT_S)."""
    process.send_signal(signal.SIGTERM)
    try:
        return process.wait(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        return -9


def poll(client: Client, info: SceneInfo, fast: bool) -> tuple[list[Frame], np.ndarray]:
    """Query every step once, paced at dt unless ``fast``; returns frames and latencies (s)."""
    frames: list[Frame] = []
    latencies = np.empty(info.steps)
    started = time.perf_counter()
    for step, t in enumerate(info.times()):
        if not fast:  # a simulator asks once per step, not back to back
            delay = started + step * info.dt - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        sent = time.perf_counter()
        frames.append(client.query(float(t)))
        latencies[step] = time.perf_counter() - sent
    return frames, latencies


def report(info: SceneInfo, frames: list[Frame], latencies: np.ndarray, stats: StatsReply) -> None:
    """Print what the client saw."""
    shape = " x ".join(str(n) for n in info.shape)
    print(f"scene {info.name}: {info.description}")
    print(f"  lattice {shape} ({info.n_points} spheres), dt {info.dt} s, {info.steps} steps, "
          f"evaluator {info.evaluator}, policy {info.policy}")  # fmt: skip
    peaks = np.array([float(np.abs(f.z).max()) for f in frames])
    peak_step = int(np.argmax(peaks))
    print(f"  {'step':>5} {'t (s)':>7} {'max |z|':>10} {'max |move| (world)':>19}")
    for frame in frames:
        if frame.step % 10 == 0 or frame.step == peak_step:
            moved = float(np.abs(frame.positions() - info.rest_positions()).max())
            mark = "  <- peak" if frame.step == peak_step else ""
            print(f"  {frame.step:>5} {frame.t:>7.2f} {peaks[frame.step]:>10.3e} "
                  f"{moved:>19.3e}{mark}")  # fmt: skip
    micros = latencies * 1e6
    p50, p99 = np.percentile(micros, [50, 99])
    print(f"  client round trip over {len(frames)} queries: p50 {p50:.0f} us, p99 {p99:.0f} us, "
          f"max {micros.max():.0f} us")  # fmt: skip
    server = stats.latency_us or {}
    print(f"  server handling ({server['count']} requests): p50 {server['p50']:.0f} us, "
          f"p99 {server['p99']:.0f} us")  # fmt: skip


def plot(info: SceneInfo, frames: list[Frame], path: Path) -> None:
    """Peak displacement over time, and the frame at the peak (needs matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    times = np.array([f.t for f in frames])
    peaks = np.array([float(np.abs(f.z).max()) for f in frames])
    peak = frames[int(np.argmax(peaks))]
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot(times, peaks)
    left.set(xlabel="t (s)", ylabel="max |z|", title=f"{info.name}: peak displacement")
    if peak.z.ndim == 2:
        image = right.imshow(peak.z.T, origin="lower", extent=(0, 1, 0, 1), cmap="viridis")
        right.set(xlabel="x", ylabel="y", title=f"z at t = {peak.t:.2f} s")
        figure.colorbar(image, ax=right)
    else:
        right.plot(info.points[:, 0], peak.z)
        right.set(xlabel="x", ylabel="z", title=f"z at t = {peak.t:.2f} s")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    """Run the demo; returns the process exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane", help="built-in scene or TOML file")
    parser.add_argument("--fast", action="store_true", help="poll back to back, not at dt")
    parser.add_argument("--plot", type=Path, default=Path("out/demo.png"), help="plot file")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    started = time.perf_counter()
    process, address = start_server(args.scene)
    print(f"server: {address} (started in {time.perf_counter() - started:.1f} s)")
    try:
        with Client(address, timeout=5.0, retries=1) as client:
            info = client.describe()
            frames, latencies = poll(client, info, args.fast)
            stats = client.stats()
    finally:
        code = stop_server(process)
    report(info, frames, latencies, stats)
    try:
        plot(info, frames, args.plot)
        print(f"plot: {args.plot}")
    except ModuleNotFoundError:
        print("plot: skipped (pip install 'membrane-tissue[plot]')")
    print(f"server stopped (exit code {code})")
    return 0 if code == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
