"""A good client's latency while the server reloads a scene (SIGHUP).

`membrane serve` on an exact 20 x 20 skin patch with dt 1e-4 (10,001 frames precomputed at
load, the slowest built-in kind of build); a client polls it once per millisecond; the scene
file is rewritten with another lattice and the server sent SIGHUP. Prints the build time, the
latency of every reply sent during the build (p50, p99, max) and how many replies were later
than 50 ms, and checks that the client's frames took the new shape.

    python benchmarks/reload.py [--rounds 3]
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "system"))

from attackers import WatchedServer

from membrane_client import Client
from membrane_client.errors import MembraneError

_SCENE = """model = "membrane-forced"
evaluator = "exact"
dt = 0.0001
duration = 1.0
[lattice]
nx = {nx}
ny = 20
"""


def _poll(
    address: str, stop: threading.Event, log: list[tuple[float, float, int]], errors: list[str]
) -> None:
    with Client(address, timeout=5.0) as client:
        step = 0
        while not stop.is_set():
            sent = time.perf_counter()
            try:
                frame = client.query((step % 10_001) * 1e-4)
            except MembraneError as exc:
                errors.append(f"{type(exc).__name__}: {exc}")
                return
            log.append((sent, time.perf_counter() - sent, frame.z.size))
            step += 1
            time.sleep(0.001)


def one_reload(server: WatchedServer, scene: Path, nx: int) -> str:
    """Reload the scene to an nx x 20 lattice under a polling client; one line of figures."""
    stop = threading.Event()
    log: list[tuple[float, float, int]] = []
    errors: list[str] = []
    poller = threading.Thread(target=_poll, args=(server.address, stop, log, errors), daemon=True)
    poller.start()
    time.sleep(0.5)
    scene.write_text(_SCENE.format(nx=nx))
    lines_before = len(server.log)
    signalled = time.perf_counter()
    server.process.send_signal(signal.SIGHUP)
    while not any("reloaded scenes" in line for line in server.log[lines_before:]):
        time.sleep(0.01)
    swapped = time.perf_counter()
    time.sleep(0.3)
    stop.set()
    poller.join(10)
    if poller.is_alive() or errors:
        raise RuntimeError(f"the polling client failed: {errors or 'still waiting after 10 s'}")
    during = np.array([seconds for sent, seconds, _ in log if signalled <= sent <= swapped]) * 1e3
    sizes = {size for _, _, size in log[-10:]}
    slowest = max((seconds, sent) for sent, seconds, _ in log if signalled <= sent <= swapped)
    where = f"slowest at {slowest[1] - signalled:.2f} s into the build"
    return (
        f"to {nx} x 20: built in {swapped - signalled:.2f} s; {during.size} replies meanwhile, "
        f"p50 {np.percentile(during, 50):.2f} ms, p99 {np.percentile(during, 99):.2f} ms, "
        f"max {during.max():.2f} ms ({where}), {int((during > 50).sum())} over 50 ms; "
        f"frames now {sorted(sizes)} points"
    )


def main(argv: list[str] | None = None) -> int:
    """Reload back and forth ``--rounds`` times and print each."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        scene = Path(folder) / "skin.toml"
        scene.write_text(_SCENE.format(nx=20))
        server = WatchedServer([str(scene)])
        try:
            for round_ in range(args.rounds):
                print(one_reload(server, scene, 30 if round_ % 2 == 0 else 20), flush=True)
        finally:
            server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
