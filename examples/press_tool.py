"""A rigid tool pressed into a live scene: does the tissue ever rise above it?

Against `membrane serve --scene membrane-live` (problem units) a sphere of radius 0.1 at the
patch's centre ramps to depth 0.01 over 0.1 s and is held for 0.2 s; against a physical scene
(`--scene skin-patch`, SI on the wire) a 5 mm sphere ramps to 0.5 mm. Every step asks for a
float64 frame, and the example checks it itself: the tool's surface over every lattice point
under it (its own formula, not the server's), the largest height of tissue above it over the
whole run, and that figure as a share of the depth. Prints the force at the end of the ramp and
of the hold with the server's contact count, and exits 1 when the penetration is over 1e-6 of
the depth.

    membrane serve --scene membrane-live &
    python examples/press_tool.py [--connect ADDR] [--scene NAME] [--kind sphere|cylinder]
                                  [--depth D] [--radius R]     (mm on a physical scene)

Needs the client only (pyzmq, msgpack, numpy).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from membrane_client import DEFAULT_ADDRESS, Client, MembraneError, SceneInfo, Tool

RAMP_S, HOLD_S = 0.1, 0.2
ALLOWED = 1e-6  # of the depth: the penetration a float64 frame may show
DEFAULTS = {False: (0.01, 0.1), True: (0.5, 5.0)}  # (depth, radius): problem units, mm


def physical(info: SceneInfo) -> bool:
    """A physical scene's lengths are in m (describe's units); a dimensionless one's are not."""
    return str(info.units.get("length", "")).split(" ", 1)[0] == "m"


def surface(kind: str, radius: float, depth: float, rho: np.ndarray) -> np.ndarray:
    """The tool's height over points at distance ``rho`` (<= radius) from its axis."""
    if kind == "cylinder":
        return np.full(rho.shape, -depth)
    return -depth + radius - np.sqrt(np.maximum(radius**2 - rho**2, 0.0))


def press(client: Client, scene: str, kind: str, depth: float | None, radius: float | None) -> int:
    with client.session(scene) as session:
        info = session.info
        assert info is not None
        scale = 1e-3 if physical(info) else 1.0  # shown mm to the wire's m
        unit = "mm" if physical(info) else "problem units"
        shown_depth, shown_radius = DEFAULTS[physical(info)]
        depth_m = scale * (shown_depth if depth is None else depth)
        radius_m = scale * (shown_radius if radius is None else radius)
        points = info.points
        at = tuple(float(c) for c in (points.min(axis=0) + points.max(axis=0)) / 2)
        rho = np.sqrt(((points - np.asarray(at)) ** 2).sum(axis=1))
        under = rho <= radius_m
        print(f"{kind} of radius {radius_m / scale:g} {unit} at {at}, depth {depth_m / scale:g}")
        print(f"lattice points under it: {int(under.sum())} of {len(points)}")
        steps = round((RAMP_S + HOLD_S) / info.dt)
        worst = -np.inf
        for k in range(steps):
            d = depth_m * min(1.0, (k + 1) * info.dt / RAMP_S)
            frame = session.step(tools=[Tool(kind, at, d, radius_m)], dtype="<f8")
            assert frame.z is not None and frame.z.dtype == np.float64
            z = frame.z.reshape(-1)[under]
            worst = max(worst, float((z - surface(kind, radius_m, d, rho[under])).max()))
            if k + 1 in (round(RAMP_S / info.dt), steps):
                reading = frame.tools[0]
                print(
                    f"t = {frame.t:.3f} s: force {reading.force:.6g} "
                    f"{'N' if physical(info) else 'problem units'}, "
                    f"{reading.contacts} of {reading.points} points in contact"
                )
        worst = max(worst, 0.0)
        share = worst / depth_m
        print(f"largest penetration over the lattice: {worst:.3g} (of the depth: {share:.3g})")
        return 0 if share <= ALLOWED else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--connect", default=DEFAULT_ADDRESS)
    parser.add_argument("--scene", default="membrane-live")
    parser.add_argument("--kind", choices=("sphere", "cylinder"), default="sphere")
    parser.add_argument("--depth", type=float, help="mm on a physical scene")
    parser.add_argument("--radius", type=float, help="mm on a physical scene")
    args = parser.parse_args(argv)
    try:
        with Client(args.connect, timeout=5.0) as client:
            return press(client, args.scene, args.kind, args.depth, args.radius)
    except MembraneError as exc:
        print(f"press_tool: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
