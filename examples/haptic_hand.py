"""A simulated haptic device on a live scene: a hand presses, slides and lets go through the
haptic loop (``membrane_client.haptics``), and feels the tissue at 1 kHz.

The device is a mass m on the hand's spring-damper (stiffness k_h, damping b_h) whose other end
follows a scripted target: down to TARGET below the rest surface in 0.2 s, 0.4 s held while it
slides SLIDE along x, back up in 0.2 s, 0.2 s at rest. Each servo tick the loop reads the
device's position, renders the coupled force, and the device integrates one tick under it
(semi-implicit Euler). Prints the force and depths every 50 ms, the settled rendered stiffness
against the tissue's, the loop's report, and writes a plot (force; device and proxy depth)
when matplotlib is installed.

    membrane serve --scene membrane-live &     # or --scene skin-patch (SI: m, N)
    python examples/haptic_hand.py [--connect ADDR] [--scene NAME] [--plot out/hand.png]

Needs the client only (pyzmq, msgpack, numpy); the plot needs matplotlib.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from membrane_client import DEFAULT_ADDRESS, Client, MembraneError
from membrane_client.haptics import HapticLoop, Tick

PRESS_S, SLIDE_S, LIFT_S, REST_S = 0.2, 0.4, 0.2, 0.2


@dataclass(frozen=True)
class Hand:
    """A scene's device and script, in the scene's units."""

    start: tuple[float, float]  # where the press begins
    slide: float  # how far it slides along x
    target: float  # the hand's target depth
    radius: float  # the tip's footprint (0: a point, on plates)
    mass: float
    stiffness: float  # k_h
    damping: float  # b_h
    unit: str


HANDS = {  # a 1 mm target on the skin (SI); 1.5e-3 on the unit membrane (problem units)
    "skin-patch": Hand((0.02, 0.025), 0.01, 1e-3, 0.0, 0.05, 400.0, 4.0, "m, N"),
    "membrane-live": Hand((0.4, 0.5), 0.2, 1.5e-3, 0.05, 0.01, 100.0, 1.0, "problem units"),
}


class Device:
    """The mass on the hand's spring, stepped once per servo tick under the rendered force."""

    def __init__(self, hand: Hand, period: float) -> None:
        self.hand, self.period = hand, period
        self.depth = self.velocity = self.t = 0.0
        self.lock = threading.Lock()
        self.ticks: list[tuple[float, float, float, float]] = []  # t, device, proxy, force

    def target(self, t: float) -> tuple[float, float]:
        """The hand's (x, depth) at time t."""
        h = self.hand
        press = min(t / PRESS_S, 1.0, max(0.0, (PRESS_S + SLIDE_S + LIFT_S - t) / LIFT_S))
        slid = min(max(0.0, (t - PRESS_S) / SLIDE_S), 1.0)
        return h.start[0] + slid * h.slide, press * h.target

    def position(self) -> tuple[float, float, float]:
        with self.lock:
            x, _ = self.target(self.t)
            return x, self.hand.start[1], self.depth

    def render(self, tick: Tick) -> None:
        h = self.hand
        with self.lock:
            _, aim = self.target(self.t)
            pull = h.stiffness * (aim - self.depth) - h.damping * self.velocity
            self.velocity += self.period * (pull - tick.force) / h.mass  # the tissue pushes up
            self.depth += self.period * self.velocity
            self.ticks.append((self.t, tick.device, tick.proxy, tick.force))
            self.t += self.period


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--connect", default=DEFAULT_ADDRESS, help=f"(default {DEFAULT_ADDRESS})")
    parser.add_argument("--scene", default="membrane-live", choices=sorted(HANDS))
    parser.add_argument("--plot", type=Path, help="write the force and depth plot (PNG)")
    args = parser.parse_args(argv)
    hand = HANDS[args.scene]
    device = Device(hand, 1e-3)
    total = PRESS_S + SLIDE_S + LIFT_S + REST_S
    try:
        with Client(args.connect, timeout=2.0) as client:
            print(f"scene {args.scene}: {client.describe(args.scene).description} ({hand.unit})")
        loop = HapticLoop(
            args.connect, args.scene, device.position, radius=hand.radius, render=device.render
        )
        with loop:
            while device.t < total:
                time.sleep(0.01)
    except MembraneError as error:
        print(f"haptic_hand: {error}", file=sys.stderr)
        return 2
    report = loop.report()
    t, depth, proxy, force = (np.array(column) for column in zip(*device.ticks, strict=True))
    print("   t (s)   device depth   proxy depth      force")
    for n in range(0, t.size, 50):
        print(f"{t[n]:8.3f} {depth[n]:14.4e} {proxy[n]:13.4e} {force[n]:10.4f}")
    held = (t > PRESS_S + 0.1) & (t < PRESS_S + SLIDE_S)
    stiffness = force[held].mean() / depth[held].mean()
    print(
        f"held while sliding: force {force[held].mean():.4g} at device depth "
        f"{depth[held].mean():.4g}: {stiffness:.4g} per unit depth (rendered)"
    )
    print(f"largest force {force.max():.4g} at t = {t[force.argmax()]:.3f} s")
    print(
        f"loop: {report.ticks} ticks, {report.missed} missed, compute p50 "
        f"{report.compute_p50_us:.0f} us, p99 {report.compute_p99_us:.0f} us; network: "
        f"{report.steps} steps, {report.skipped} skipped, {report.stale_ticks} stale ticks"
    )
    if args.plot is not None:
        _plot(args.plot, t, depth, proxy, force, hand.unit)
    return 0


def _plot(
    path: Path, t: np.ndarray, depth: np.ndarray, proxy: np.ndarray, force: np.ndarray, unit: str
) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("no plot: matplotlib is not installed (pip install matplotlib)")
        return
    figure, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    top.plot(t, force)
    top.set_ylabel(f"force ({unit.split(', ')[-1]})")
    bottom.plot(t, depth, label="device")
    bottom.plot(t, proxy, label="proxy (tissue under the tip)")
    bottom.set_ylabel(f"depth ({unit.split(', ')[0]})")
    bottom.set_xlabel("t (s)")
    bottom.legend()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
