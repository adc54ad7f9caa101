"""`membrane coppelia`: drive the served lattice as spheres in CoppeliaSim.

This module imports with the core dependencies only; the CoppeliaSim remote API client (the
``coppelia`` extra) is imported when the command runs.

With ``--probe OBJECT_PATH`` (a live scene) a scene object presses the tissue each step
(:mod:`membrane_coppelia.probe`); ``--force-signal NAME`` writes the contact force back.

Exit codes: 0 the run ended (its end time, its step limit, or the scene's ``error`` policy
refusing a time, which is reported); 1 CoppeliaSim or the membrane server did not answer within
the timeout, or refused a call; 2 bad input (arguments, an unknown scene, a scene that is not
live for ``--probe``, no such probe object); 130 / 143 interrupted by SIGINT / SIGTERM (the
simulation was stopped first, so that CoppeliaSim is not left waiting for this client).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from typing import TYPE_CHECKING

from membrane_cli.arguments import UsageError, bounded_float, bounded_int
from membrane_cli.connection import add_connection_arguments
from membrane_client.errors import UserError

if TYPE_CHECKING:
    from membrane_coppelia.interrupt import Interrupted
    from membrane_coppelia.options import RunOptions

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
        help="simulation time to run to, s (default: the scene's end; with --probe, no end)",
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
    parser.add_argument(
        "--remote-timeout",
        type=POSITIVE,
        default=20.0,
        help=(
            "seconds CoppeliaSim's remote API add-on waits for this client before forgetting it "
            "(default 20): if the adapter is killed (SIGKILL) mid-run, the simulation is "
            "released within this time instead of the client library's 600 s"
        ),
    )
    live = parser.add_argument_group("live scenes (a probe presses the tissue)")
    live.add_argument(
        "--probe",
        metavar="OBJECT_PATH",
        default=None,
        help=(
            "a scene object (e.g. /UR5/tip, or a dummy you drag) that presses the tissue: each "
            "step its position becomes a probe of the live session (needs a live scene)"
        ),
    )
    live.add_argument(
        "--probe-radius",
        type=POSITIVE,
        default=0.05,
        help="the probe tip's radius in problem units (default 0.05)",
    )
    live.add_argument(
        "--force-signal",
        metavar="NAME",
        default=None,
        help=(
            "write the contact force to this float signal each step (a scene property "
            "'signal.NAME' on CoppeliaSim 4.8+, sim.setFloatSignal before); needs --probe"
        ),
    )
    parser.set_defaults(handler=_run_coppelia)


class _Progress:
    """Prints the step count to stderr about once a second (long runs show they are alive)."""

    def __init__(self) -> None:
        self._last = time.monotonic()
        self._tty = sys.stderr.isatty()

    def __call__(self, steps: int, t: float, force: float | None = None) -> None:
        now = time.monotonic()
        if now - self._last < PROGRESS_EVERY_S:
            return
        self._last = now
        shown = f"step {steps}  t = {t:.3f} s"
        if force is not None:
            shown += f"  force = {force:.4g}"
        if self._tty:
            print(f"\r{shown}", end="", file=sys.stderr, flush=True)
        else:
            log.info("%s", shown)

    def done(self) -> None:
        if self._tty:
            print("\r\033[K", end="", file=sys.stderr, flush=True)


def _run_coppelia(args: argparse.Namespace) -> int:
    from membrane_client.errors import ServerError, Timeout
    from membrane_client.protocol import ErrorCode
    from membrane_coppelia.interrupt import Interrupted, interrupt_on
    from membrane_coppelia.lattice import LatticeStyle
    from membrane_coppelia.link import SimulatorError
    from membrane_coppelia.options import RunOptions

    if args.force_signal is not None and args.probe is None:
        raise UsageError("--force-signal needs --probe (the force comes from the probe)")
    options = RunOptions(
        server=args.connect,
        scene=args.scene,
        server_timeout=args.timeout,
        sim_host=args.sim_host,
        sim_port=args.sim_port,
        sim_timeout=args.sim_timeout,
        remote_timeout=args.remote_timeout,
        style=LatticeStyle(sphere_size=args.sphere_size, color=args.color),
        batched=not args.per_sphere,
        keep=args.keep,
        duration=args.duration,
        max_steps=args.steps,
    )
    progress = _Progress()
    try:
        with interrupt_on():
            run = _run_probe if args.probe else _run_film
            lines = run(args, options, progress)
    except Interrupted as exc:
        progress.done()
        print(f"membrane coppelia: {_interrupted(exc)}", file=sys.stderr)
        return exc.exit_code
    except SimulatorError as exc:
        progress.done()
        if isinstance(exc, UserError):
            raise  # no such probe object: the dispatcher's one line, exit code 2
        print(f"membrane coppelia: {exc}", file=sys.stderr)
        return 1
    except Timeout as exc:
        progress.done()
        print(f"membrane coppelia: membrane server: {exc}", file=sys.stderr)
        return 1
    except ServerError as exc:
        progress.done()
        hint = " (--probe needs a live scene, e.g. membrane-live)" if exc.code == "not_live" else ""
        print(f"membrane coppelia: membrane server refused: {exc}{hint}", file=sys.stderr)
        bad_input = exc.code in (
            ErrorCode.UNKNOWN_SCENE,
            ErrorCode.INVALID_TIME,
            ErrorCode.NOT_LIVE,
            ErrorCode.BAD_REQUEST,
        )
        return 2 if bad_input else 1
    progress.done()
    for line in lines:
        print(line)
    return 0


def _interrupted(exc: Interrupted) -> str:
    if exc.simulator_released is False:
        return f"interrupted by {exc.name}; could not stop the simulation (see above)"
    if exc.simulator_released:
        return f"interrupted by {exc.name}: stopped the simulation (stepping released)"
    return f"interrupted by {exc.name}"


def _run_film(args: argparse.Namespace, options: RunOptions, progress: _Progress) -> list[str]:
    from membrane_coppelia.film import drive_lattice

    result = drive_lattice(options, on_step=progress)
    return [
        f"scene {result.scene}: {result.spheres} spheres moved {result.path}: {result.message}",
        f"simulator dt {result.sim_dt:g} s; per step p50/p99: {result.timings.summary()}",
    ]


def _run_probe(args: argparse.Namespace, options: RunOptions, progress: _Progress) -> list[str]:
    from membrane_coppelia.probe import drive_probe

    result = drive_probe(
        args.probe,
        options,
        radius=args.probe_radius,
        force_signal=args.force_signal,
        on_step=progress,
    )
    lines = [
        f"scene {result.scene}: {result.spheres} spheres moved {result.path}, pressed by "
        f"{args.probe}: {result.message}",
        f"simulator dt {result.sim_dt:g} s; per step p50/p99: {result.timings.summary()}",
    ]
    if result.signal is not None:
        lines.append(f"contact force written each step with {result.signal}")
    return lines
