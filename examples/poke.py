"""A scripted finger pokes the live membrane: press, hold, let go, and watch it ring.

Against `membrane serve --scene membrane-live` (20 x 20, stepped at 1 kHz): a probe of radius
0.05 at the patch's centre ramps to DEPTH over 0.2 s, holds for 0.2 s, and lifts off; the patch
then rings for 0.4 s (the scene's damping is 2 %). Prints the contact force against the depth
while pressing, the ringing of the centre after release, the step round-trip latency, and
writes a plot when matplotlib is installed.

    membrane serve --scene membrane-live &
    python examples/poke.py [--connect ADDR] [--depth 0.001] [--plot out/poke.png] [--realtime]

Needs the client only (pyzmq, msgpack, numpy); the plot needs matplotlib.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from membrane_client import DEFAULT_ADDRESS, Client, LiveFrame, MembraneError, Probe

RAMP_S, HOLD_S, RING_S = 0.2, 0.2, 0.4
CENTRE, RADIUS = (0.5, 0.5), 0.05
PRINT_EVERY_S = 0.02


def depth_at(t: float, depth: float) -> float | None:
    """The finger's depth at time t (None once it has lifted off)."""
    if t <= RAMP_S:
        return depth * t / RAMP_S
    return depth if t <= RAMP_S + HOLD_S else None


def poke(client: Client, depth: float, realtime: bool) -> dict[str, np.ndarray]:
    """Run the poke; returns time series of t, depth, force and the centre's displacement."""
    rows: dict[str, list[float]] = {"t": [], "depth": [], "force": [], "centre": [], "rtt_us": []}
    with client.session("membrane-live") as session:
        assert session.info is not None
        dt, shape = session.info.dt, session.info.shape
        centre = (shape[0] // 2, shape[1] // 2)
        steps = round((RAMP_S + HOLD_S + RING_S) / dt)
        started = time.perf_counter()
        for k in range(steps):
            t = (k + 1) * dt  # the time at the end of this step, where the contact is solved
            d = depth_at(t, depth)
            probes = [] if d is None else [Probe(CENTRE, d, RADIUS)]
            sent = time.perf_counter()
            frame: LiveFrame = session.step(probes=probes)
            rows["rtt_us"].append((time.perf_counter() - sent) * 1e6)
            assert frame.z is not None
            rows["t"].append(frame.t)
            rows["depth"].append(np.nan if d is None else d)
            rows["force"].append(frame.probes[0].force if frame.probes else 0.0)
            rows["centre"].append(float(frame.z[centre]))
            if realtime:
                time.sleep(max(0.0, started + (k + 1) * dt - time.perf_counter()))
    return {key: np.asarray(values) for key, values in rows.items()}


def report(series: dict[str, np.ndarray]) -> None:
    t, depth, force, centre = series["t"], series["depth"], series["force"], series["centre"]
    every = max(1, round(PRINT_EVERY_S / (t[1] - t[0])))
    print("pressing: depth -> contact force (the tool feels it along +axis)")
    print(f"{'t (s)':>8} {'depth':>10} {'force':>10} {'centre z':>11}")
    pressing = np.flatnonzero(~np.isnan(depth))
    for i in pressing[every - 1 :: every]:
        print(f"{t[i]:8.3f} {depth[i]:10.2e} {force[i]:10.4f} {centre[i]:11.3e}")
    held = pressing[-1]
    stiffness = force[held] / depth[held]
    print(f"stiffness at full depth: {stiffness:.2f} force per unit depth")
    print("released: the centre rings (damping 2 %)")
    released = np.flatnonzero(np.isnan(depth))
    for i in released[every - 1 :: every]:
        print(f"{t[i]:8.3f} {'-':>10} {force[i]:10.4f} {centre[i]:11.3e}")
    crossings = np.flatnonzero(np.diff(np.sign(centre[released])) != 0)
    if len(crossings) >= 3:
        period = 2 * np.mean(np.diff(t[released][crossings]))
        print(f"ringing period {period * 1e3:.1f} ms ({1 / period:.1f} Hz)")
    rtt = series["rtt_us"]
    print(
        f"step round trip: p50 {np.percentile(rtt, 50):.0f} us, p99 {np.percentile(rtt, 99):.0f}"
        f" us over {len(rtt)} steps"
    )


def plot(series: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    top.plot(series["t"], series["force"], color="tab:red")
    top.set_ylabel("contact force")
    top.set_title("a finger pokes the live membrane")
    bottom.plot(series["t"], -series["depth"], "--", color="gray", label="finger face (-depth)")
    bottom.plot(series["t"], series["centre"], color="tab:blue", label="centre displacement")
    bottom.set_xlabel("t (s)")
    bottom.set_ylabel("displacement")
    bottom.legend(loc="lower right")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    print(f"wrote {path}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", default=DEFAULT_ADDRESS, help="the membrane server")
    parser.add_argument("--depth", type=float, default=0.001, help="deepest press (problem units)")
    parser.add_argument("--plot", type=Path, default=Path("out/poke.png"), help="plot file")
    parser.add_argument("--realtime", action="store_true", help="pace the steps at dt")
    args = parser.parse_args()
    if not args.depth > 0:
        parser.error(f"--depth must be > 0, got {args.depth}")
    try:
        with Client(args.connect, timeout=2.0) as client:
            series = poke(client, args.depth, args.realtime)
    except MembraneError as exc:
        print(f"poke: {args.connect}: {exc}", file=sys.stderr)
        return 1
    report(series)
    try:
        plot(series, args.plot)
    except ModuleNotFoundError:
        print("poke: no plot (matplotlib is not installed)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
