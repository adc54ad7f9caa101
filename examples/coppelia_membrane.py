"""The membrane demo in CoppeliaSim: a 20 x 20 lattice of spheres moved by the forced membrane.

As in the reference study: 20 x 20 spheroids (0.05 across) on [0, 1]^2 at height 1, static and
respondable, the simulation in stepping mode. Unlike the study, the simulator's clock drives the
queries (one per step, at the step's simulation time), the run stops at the end of the time
domain the model was trained on, and the spheres move with one remote call per step. The display
factor on the displacement is the scene's ``placement.scale``.

Run it with CoppeliaSim 4.6+ open (ZeroMQ remote API on port 23000)::

    python examples/coppelia_membrane.py                     # serves the `membrane` scene itself
    python examples/coppelia_membrane.py --connect tcp://127.0.0.1:5555   # or a running server

Without CoppeliaSim, the stand-in plays its part::

    python -m membrane_coppelia.standin --port 23000 &
    python examples/coppelia_membrane.py
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from membrane_client import Client
from membrane_coppelia.film import run_film
from membrane_coppelia.lattice import LatticeStyle, SphereLattice
from membrane_coppelia.link import DEFAULT_SIM_PORT, SimulatorError
from membrane_coppelia.options import RunOptions

SCENE = "membrane"
LATTICE_SHAPE = (20, 20)
STYLE = LatticeStyle(sphere_size=0.05, color=(0.85, 0.35, 0.30))

log = logging.getLogger("coppelia_membrane")


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


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", help="membrane server address (default: serve one here)")
    parser.add_argument("--sim-host", default="127.0.0.1", help="CoppeliaSim host")
    parser.add_argument("--sim-port", type=int, default=DEFAULT_SIM_PORT, help="CoppeliaSim port")
    parser.add_argument("--steps", type=int, default=None, help="stop after this many steps")
    parser.add_argument("--per-sphere", action="store_true", help="one call per sphere per step")
    parser.add_argument("--keep", action="store_true", help="leave the spheres in the scene")
    parser.add_argument("--sim-timeout", type=float, default=5.0, help="seconds per reply")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; returns the exit code (1 when CoppeliaSim does not answer)."""
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    options = RunOptions(
        server_timeout=2.0,
        sim_host=args.sim_host,
        sim_port=args.sim_port,
        sim_timeout=args.sim_timeout,
        style=STYLE,
        batched=not args.per_sphere,
        keep=args.keep,
        max_steps=args.steps,
    )
    try:
        link = options.connect_simulator()
    except SimulatorError as exc:
        print(f"coppelia_membrane: {exc}", file=sys.stderr)
        return 1
    try:
        with (
            membrane_server(args.connect, SCENE) as address,
            Client(address, timeout=options.server_timeout) as client,
            SphereLattice(
                link.sim,
                client,
                style=options.style,
                batched=options.batched,
                keep=options.keep,
                address=link.address,
                timeout=options.sim_timeout,
            ) as lattice,
        ):
            info = client.describe()
            if info.shape != LATTICE_SHAPE:
                log.warning(
                    "scene %s has a %s lattice, not %s", info.name, info.shape, LATTICE_SHAPE
                )
            lattice.build()
            result = run_film(lattice, max_steps=options.max_steps)
    except SimulatorError as exc:
        print(f"coppelia_membrane: {exc}", file=sys.stderr)
        return 1
    finally:
        link.close()
    print(f"{result.spheres} spheres, moved {result.path}: {result.message}")
    print(f"per step p50/p99: {result.timings.summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
