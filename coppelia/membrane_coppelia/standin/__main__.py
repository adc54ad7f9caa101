"""``python -m membrane_coppelia.standin``: the stand-in in the foreground, until interrupted.

The adapter (or any remote API client) then talks to it as to CoppeliaSim on that port.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Sequence
from types import FrameType

import zmq

from membrane_coppelia.standin.addon import CoppeliaStandin
from membrane_coppelia.standin.scene import RELEASES

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the stand-in in the foreground until interrupted (SIGINT or SIGTERM)."""
    parser = argparse.ArgumentParser(
        prog="python -m membrane_coppelia.standin",
        description="A stand-in for CoppeliaSim's ZeroMQ remote API (protocol 2), on loopback.",
    )
    parser.add_argument("--port", type=int, default=23000, help="TCP port; 0 picks a free one")
    parser.add_argument("--dt", type=float, default=0.05, help="initial simulation time step (s)")
    parser.add_argument(
        "--sim-version",
        choices=sorted(RELEASES),
        default="4.9",
        help="the CoppeliaSim release to play (the calls it offers; default 4.9)",
    )
    parser.add_argument(
        "--stop-answering-after",
        type=int,
        default=None,
        metavar="N",
        help="reply to N requests, then never again (simulates a hung CoppeliaSim)",
    )
    parser.add_argument(
        "--no-scripts",
        action="store_true",
        help="offer no script calls (batched moves unavailable)",
    )
    args = parser.parse_args(argv)
    if not 0 <= args.port <= 65535:
        parser.error(f"--port must be in 0..65535, got {args.port}")
    if not args.dt > 0.0:
        parser.error(f"--dt must be > 0, got {args.dt}")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        standin = CoppeliaStandin(
            port=args.port,
            dt=args.dt,
            answer_limit=args.stop_answering_after,
            scripts=not args.no_scripts,
            version=args.sim_version,
        )
    except zmq.ZMQError as exc:
        print(f"coppelia stand-in: cannot bind port {args.port}: {exc}", file=sys.stderr)
        return 2

    def _stop(signum: int, frame: FrameType | None) -> None:
        standin.request_stop()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    # The first line is read by scripts (benchmarks/coppelia_paths.py): keep its start.
    print(
        f"coppelia stand-in listening on {standin.address} (CoppeliaSim {args.sim_version})",
        flush=True,
    )
    standin.serve()
    standin.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
