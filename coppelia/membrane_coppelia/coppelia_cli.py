"""`membrane coppelia`: drive the served lattice as spheres in CoppeliaSim.

This module imports with the core dependencies only; the CoppeliaSim remote API client (the
``coppelia`` extra) is imported when the command runs.

Exit codes: 0 the run ended (its end time, its step limit, or the scene's ``error`` policy
refusing a time, which is reported); 1 CoppeliaSim or the membrane server did not answer within
the timeout, or refused a call; 2 bad input (arguments, an unknown scene).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

from membrane_cli.arguments import bounded_float, bounded_int
from membrane_cli.connection import add_connection_arguments

__all__ = ["add_coppelia"]

POSITIVE = bounded_float(0.0, exclusive=True)
NON_NEGATIVE = bounded_float(0.0)

log = logging.getLogger(__name__)

PROGRESS_EVERY_S = 1.0


def _color(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        rgb = tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R,G,B numbers, got {text!r}") from None
    if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
        raise argparse.ArgumentTypeError(f"expected 3 values in [0, 1] as R,G,B, got {text!r}")
    return (rgb[0], rgb[1], rgb[2])


def add_coppelia(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane coppelia`."""
    parser = subparsers.add_parser(
        "coppelia",
        help="drive the served lattice as spheres in CoppeliaSim (stepping mode)",
        description=(
            "Build the lattice the membrane server describes as spheres in CoppeliaSim (through "
            "its ZeroMQ remote API, port 23000 by default), run the simulation in stepping mode "
            "querying the server at every step's simulation time, move every sphere, report "
            "per-step times, stop, and remove the spheres (unless --keep). The spheres move with "
            "one remote call per step through a script function installed in the scene, or one "
            "call per sphere with --per-sphere (or when the script cannot be installed). Needs "
            "the 'coppelia' extra."
        ),
    )
    add_connection_arguments(parser, timeout=1.0, curve=False)  # the membrane server
    parser.add_argument("--scene", default=None, help="scene name, where the server hosts several")
    parser.add_argument("--sim-host", default="127.0.0.1", help="CoppeliaSim host")
    parser.add_argument(
        "--sim-port",
        type=bounded_int(1, 65535, why="a TCP port"),
        default=23000,
        help="CoppeliaSim ZeroMQ remote API port",
    )
    parser.add_argument(
        "--duration",
        type=NON_NEGATIVE,
        default=None,
        help="simulation time to run to, s (default: the scene's end)",
    )
    parser.add_argument(
        "--steps", type=bounded_int(0), default=None, help="stop after this many steps"
    )
    parser.add_argument(
        "--per-sphere",
        action="store_true",
        help="one setObjectPosition call per sphere per step instead of one batched call",
    )
    parser.add_argument(
        "--keep", action="store_true", help="leave the spheres in the scene after the run"
    )
    parser.add_argument(
        "--sphere-size", type=POSITIVE, default=0.05, help="sphere diameter (world units)"
    )
    parser.add_argument(
        "--color", type=_color, default=(0.85, 0.35, 0.30), help="sphere colour R,G,B in [0, 1]"
    )
    parser.add_argument(
        "--sim-timeout",
        type=POSITIVE,
        default=5.0,
        help="seconds to wait for each CoppeliaSim reply (default 5)",
    )
    parser.set_defaults(handler=_run_coppelia)


class _Progress:
    """Prints the step count to stderr about once a second (long runs show they are alive)."""

    def __init__(self) -> None:
        self._last = time.monotonic()
        self._tty = sys.stderr.isatty()

    def __call__(self, steps: int, t: float) -> None:
        now = time.monotonic()
        if now - self._last < PROGRESS_EVERY_S:
            return
        self._last = now
        if self._tty:
            print(f"\rstep {steps}  t = {t:.3f} s", end="", file=sys.stderr, flush=True)
        else:
            log.info("step %d, t = %.3f s", steps, t)

    def done(self) -> None:
        if self._tty:
            print("\r\033[K", end="", file=sys.stderr, flush=True)


def _run_coppelia(args: argparse.Namespace) -> int:
    from membrane_client.errors import ServerError, Timeout
    from membrane_client.protocol import ErrorCode
    from membrane_coppelia.coppelia import (
        LatticeStyle,
        SimulatorError,
        drive_lattice,
    )

    style = LatticeStyle(sphere_size=args.sphere_size, color=args.color)
    progress = _Progress()
    try:
        result = drive_lattice(
            args.connect,
            scene=args.scene,
            sim_host=args.sim_host,
            sim_port=args.sim_port,
            duration=args.duration,
            max_steps=args.steps,
            batched=not args.per_sphere,
            keep=args.keep,
            style=style,
            sim_timeout=args.sim_timeout,
            server_timeout=args.timeout,
            on_step=progress,
        )
    except SimulatorError as exc:
        progress.done()
        print(f"membrane coppelia: {exc}", file=sys.stderr)
        return 1
    except Timeout as exc:
        progress.done()
        print(f"membrane coppelia: membrane server: {exc}", file=sys.stderr)
        return 1
    except ServerError as exc:
        progress.done()
        print(f"membrane coppelia: membrane server refused: {exc}", file=sys.stderr)
        bad_input = exc.code in (ErrorCode.UNKNOWN_SCENE, ErrorCode.INVALID_TIME)
        return 2 if bad_input else 1
    progress.done()
    print(f"scene {result.scene}: {result.spheres} spheres moved {result.path}: {result.message}")
    print(f"simulator dt {result.sim_dt:g} s; per step p50/p99: {result.timings.summary()}")
    return 0
