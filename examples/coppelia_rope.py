"""The rope demo in CoppeliaSim: 100 spheres on a line, moved by the forced string.

As in the reference study: 100 spheroids (0.05 across) on x in [0, 1] at height 1, static and
respondable, the simulation in stepping mode; unlike it, one query per simulation step at the
step's simulation time, a run that ends with the model's time domain, and one remote call per
step to move the whole rope. The displacement shows magnified by the scene's
``placement.scale``. This example uses the one-call API, :func:`drive_lattice`;
``coppelia_membrane.py`` shows the steps it takes.

Run it with CoppeliaSim 4.6+ open (ZeroMQ remote API on port 23000)::

    python examples/coppelia_rope.py                          # serves the `rope` scene itself
    python examples/coppelia_rope.py --connect tcp://127.0.0.1:5555   # or a running server

Without CoppeliaSim: ``python -m membrane_coppelia.standin --port 23000`` first.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from membrane_coppelia.film import drive_lattice
from membrane_coppelia.lattice import LatticeStyle
from membrane_coppelia.link import DEFAULT_SIM_PORT, SimulatorError
from membrane_coppelia.options import RunOptions

SCENE = "rope"
STYLE = LatticeStyle(sphere_size=0.05, color=(0.30, 0.45, 0.85), name="rope")


@contextmanager
def membrane_server(address: str | None, scene: str) -> Iterator[str]:
    """The address of a server on ``scene``: ``address`` if given, else one started here."""
    if address is not None:
        yield address
        return
    from membrane_server.server import Server  # needs the `server` extra

    server = Server([scene], bind="tcp://127.0.0.1:*")
    try:
        yield server.start()
    finally:
        server.stop()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; returns the exit code (1 when CoppeliaSim does not answer)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", help="membrane server address (default: serve one here)")
    parser.add_argument("--sim-host", default="127.0.0.1", help="CoppeliaSim host")
    parser.add_argument("--sim-port", type=int, default=DEFAULT_SIM_PORT, help="CoppeliaSim port")
    parser.add_argument("--steps", type=int, default=None, help="stop after this many steps")
    parser.add_argument("--per-sphere", action="store_true", help="one call per sphere per step")
    parser.add_argument("--keep", action="store_true", help="leave the spheres in the scene")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        with membrane_server(args.connect, SCENE) as address:
            options = RunOptions(
                server=address,
                sim_host=args.sim_host,
                sim_port=args.sim_port,
                style=STYLE,
                batched=not args.per_sphere,
                keep=args.keep,
                max_steps=args.steps,
            )
            result = drive_lattice(options)
    except SimulatorError as exc:
        print(f"coppelia_rope: {exc}", file=sys.stderr)
        return 1
    print(f"{result.spheres} spheres, moved {result.path}: {result.message}")
    print(f"per step p50/p99: {result.timings.summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
