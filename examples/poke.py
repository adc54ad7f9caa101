"""A scripted finger pokes a live scene: press, hold, let go, and watch it ring.

Against `membrane serve --scene membrane-live` (20 x 20, stepped at 1 kHz, problem units): a
probe of radius 0.05 at the patch's centre ramps to DEPTH over 0.2 s, holds for 0.2 s, and
lifts off; the patch then rings for 0.4 s (the scene's damping is 2 %). Against a physical scene
(`--scene skin-patch`, SI units on the wire) the depth and radius are given in mm and the force
read in N; the probe is a point (radius 0, which plates allow) at the middle of the scene's
extent unless --radius is given. Prints the contact force against the depth while pressing,
the whole force history's extremes (the first steps of a press spike: a table of every 20th
step would hide them), the ringing of the centre after release, the step round-trip latency,
and writes a plot when matplotlib is installed.

    membrane serve --scene membrane-live &
    python examples/poke.py [--connect ADDR] [--scene NAME] [--depth D] [--radius R]
                            [--plot out/poke.png] [--realtime]

Needs the client only (pyzmq, msgpack, numpy); the plot needs matplotlib.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from membrane_client import DEFAULT_ADDRESS, Client, LiveFrame, MembraneError, Probe, SceneInfo

RAMP_S, HOLD_S, RING_S = 0.2, 0.2, 0.4
PRINT_EVERY_S = 0.02
FIRST_STEPS = 5  # of the press, printed one by one
DIMENSIONLESS_DEPTH, DIMENSIONLESS_RADIUS = 0.001, 0.05  # problem units
PHYSICAL_DEPTH_MM = 0.5


@dataclass(frozen=True)
class Units:
    """How the example shows a scene's numbers: a physical scene's m and N as mm and N (a
    poke is a fraction of a millimetre), a dimensionless scene's problem units as they are."""

    physical: bool
    length: str  # the shown length unit
    force: str  # the shown force unit
    per_wire_length: float  # shown length per wire length: 1000 (mm per m) or 1

    @classmethod
    def of(cls, info: SceneInfo) -> Units:
        """From describe's ``units``: a physical scene's length is "m" (its first word, the
        rest is commentary); a dimensionless scene has none, only "problem units"."""
        length = str(info.units.get("length", "")).split(" ", 1)[0]
        if length == "m":
            return cls(True, "mm", "N", 1e3)
        return cls(False, "problem units", "problem units", 1.0)

    def to_wire(self, shown: float) -> float:
        """A shown length (mm or problem units) in the wire's (m or problem units)."""
        return shown / self.per_wire_length

    def shown(self, wire: np.ndarray | float) -> np.ndarray | float:
        """A wire length in the shown unit."""
        return wire * self.per_wire_length


@dataclass(frozen=True)
class Poke:
    """The finger, in the wire's units: where it presses, how deep at most, how wide."""

    at: tuple[float, ...]
    depth: float
    radius: float

    def depth_at(self, t: float) -> float | None:
        """The finger's depth at time t (None once it has lifted off)."""
        if t <= RAMP_S:
            return self.depth * t / RAMP_S
        return self.depth if t <= RAMP_S + HOLD_S else None


def plan(info: SceneInfo, units: Units, depth: float | None, radius: float | None) -> Poke:
    """The poke for a scene: depth and radius given in the shown units (defaults: 0.5 mm and a
    point on a physical scene, 0.001 and 0.05 on a dimensionless one), at the middle of the
    scene's extent (the dimensionless scenes' [0, 1] box: (0.5, 0.5))."""
    lower, upper = info.extent
    at = tuple(float(c) for c in (lower + upper) / 2)
    if units.physical:
        shown_depth = PHYSICAL_DEPTH_MM if depth is None else depth
        shown_radius = 0.0 if radius is None else radius
    else:
        shown_depth = DIMENSIONLESS_DEPTH if depth is None else depth
        shown_radius = DIMENSIONLESS_RADIUS if radius is None else radius
    return Poke(at, units.to_wire(shown_depth), units.to_wire(shown_radius))


def poke(client: Client, scene: str, finger: Poke, realtime: bool) -> dict[str, np.ndarray]:
    """Run the poke; returns time series of t, depth, force and the centre's displacement (the
    wire's units)."""
    rows: dict[str, list[float]] = {"t": [], "depth": [], "force": [], "centre": [], "rtt_us": []}
    with client.session(scene) as session:
        assert session.info is not None
        dt, shape = session.info.dt, session.info.shape
        centre = tuple(n // 2 for n in shape)
        steps = round((RAMP_S + HOLD_S + RING_S) / dt)
        started = time.perf_counter()
        for k in range(steps):
            t = (k + 1) * dt  # the time at the end of this step, where the contact is solved
            d = finger.depth_at(t)
            probes = [] if d is None else [Probe(finger.at, d, finger.radius)]
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


def damping_of(info: SceneInfo) -> str:
    """The live engine's damping as describe gives it: one ratio, or a range per mode."""
    damping, ratios = info.live.get("damping"), info.live.get("damping_range")
    if isinstance(damping, int | float):
        return f"{100 * damping:g} %"
    if isinstance(ratios, list) and len(ratios) == 2:
        return f"per mode, {100 * ratios[0]:.3g} .. {100 * ratios[1]:.3g} %"
    return "unknown"


def shown_series(series: dict[str, np.ndarray], units: Units) -> dict[str, np.ndarray]:
    """The series with lengths in the shown unit (forces are N or problem units already)."""
    return {
        **series,
        "depth": np.asarray(units.shown(series["depth"])),
        "centre": np.asarray(units.shown(series["centre"])),
    }


def report(series: dict[str, np.ndarray], units: Units, finger: Poke, damping: str) -> None:
    """Print the press, the extremes of the force, the release and the latency."""
    t, depth, force, centre = series["t"], series["depth"], series["force"], series["centre"]
    every = max(1, round(PRINT_EVERY_S / (t[1] - t[0])))
    length, newton = units.length, units.force
    at = ", ".join(f"{units.shown(a):g}" for a in finger.at)
    print(f"probe at ({at}) {length}, radius {units.shown(finger.radius):g} {length}")
    print(f"pressing: depth ({length}) -> contact force ({newton}; the tool feels it along +axis)")
    print(f"{'t (s)':>8} {'depth':>10} {'force':>10} {'centre z':>11}")
    pressing = np.flatnonzero(~np.isnan(depth))
    for i in pressing[every - 1 :: every]:
        print(f"{t[i]:8.3f} {depth[i]:10.2e} {force[i]:10.4f} {centre[i]:11.3e}")
    report_hold(t, depth, force, pressing, units)
    report_extremes(t, force, pressing, units)
    print(f"released: the centre rings (damping {damping})")
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


def report_hold(
    t: np.ndarray, depth: np.ndarray, force: np.ndarray, pressing: np.ndarray, units: Units
) -> None:
    """The force at full depth: the last held step's, and the mean over the hold's second half
    (the press rings the tissue; the mean sits on the static value)."""
    held = pressing[-1]
    settled = pressing[(t[pressing] > RAMP_S + HOLD_S / 2)]
    mean = float(np.mean(force[settled])) if len(settled) else float(force[held])
    length, newton = units.length, units.force
    print(
        f"held at depth {depth[held]:.4g} {length}: force {force[held]:.6g} {newton} at "
        f"t = {t[held]:.3f} s, mean {mean:.6g} {newton} over the hold's second half"
    )
    stiffness = force[held] / depth[held]
    if units.physical:
        print(
            f"stiffness at full depth: {stiffness:.4g} N/mm (compliance {1 / stiffness:.4g} mm/N)"
        )
    else:
        print(f"stiffness at full depth: {stiffness:.2f} force per unit depth")


def report_extremes(t: np.ndarray, force: np.ndarray, pressing: np.ndarray, units: Units) -> None:
    """The whole history's extremes, every step counted: the peak and when, the largest jump
    between two steps, and the press's first steps one by one."""
    newton = units.force
    peak = int(np.argmax(force))
    print(
        f"force history ({len(force)} steps): max {force[peak]:.6g} {newton} at t = {t[peak]:.3f} s"
    )
    jumps = np.diff(force, prepend=0.0)
    jump = int(np.argmax(np.abs(jumps)))
    print(
        f"largest step-to-step jump: {jumps[jump]:+.6g} {newton} into t = {t[jump]:.3f} s "
        f"(step {jump + 1})"
    )
    first = pressing[:FIRST_STEPS]
    steps = ", ".join(f"{force[i]:.4g}" for i in first)
    print(f"force at the press's first {len(first)} steps ({newton}): {steps}")


def plot(series: dict[str, np.ndarray], units: Units, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    top.plot(series["t"], series["force"], color="tab:red")
    top.set_ylabel(f"contact force ({units.force})")
    top.set_title("a finger pokes the live scene")
    bottom.plot(series["t"], -series["depth"], "--", color="gray", label="finger face (-depth)")
    bottom.plot(series["t"], series["centre"], color="tab:blue", label="centre displacement")
    bottom.set_xlabel("t (s)")
    bottom.set_ylabel(f"displacement ({units.length})")
    bottom.legend(loc="lower right")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    print(f"wrote {path}")


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", default=DEFAULT_ADDRESS, help="the membrane server")
    parser.add_argument("--scene", default="membrane-live", help="the live scene to poke")
    parser.add_argument(
        "--depth",
        type=float,
        help="deepest press: mm on a physical scene (default 0.5), else problem units (0.001)",
    )
    parser.add_argument(
        "--radius",
        type=float,
        help="the probe's radius: mm on a physical scene (default 0, a point), else problem"
        " units (0.05)",
    )
    parser.add_argument("--plot", type=Path, default=Path("out/poke.png"), help="plot file")
    parser.add_argument("--realtime", action="store_true", help="pace the steps at dt")
    args = parser.parse_args()
    if args.depth is not None and not args.depth > 0:
        parser.error(f"--depth must be > 0, got {args.depth}")
    if args.radius is not None and not args.radius >= 0:
        parser.error(f"--radius must be >= 0, got {args.radius}")
    return args


def main() -> int:
    args = parse_arguments()
    try:
        with Client(args.connect, timeout=2.0) as client:
            info = client.describe(args.scene)
            units = Units.of(info)
            finger = plan(info, units, args.depth, args.radius)
            series = poke(client, args.scene, finger, args.realtime)
    except MembraneError as exc:
        print(f"poke: {args.connect}: {exc}", file=sys.stderr)
        return 1
    print(f"scene {info.name}: {info.description}")
    shown = shown_series(series, units)
    report(shown, units, finger, damping_of(info))
    try:
        plot(shown, units, args.plot)
    except ModuleNotFoundError:
        print("poke: no plot (matplotlib is not installed)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
