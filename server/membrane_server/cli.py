"""`membrane serve`: load scenes, bind, answer until SIGTERM/SIGINT.

Imports here are the core dependencies only; the server (onnxruntime, pydantic, scipy) is
imported by the handler, so a client-only install still lists the command.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

__all__ = ["add_serve"]

DEFAULT_BIND = "tcp://127.0.0.1:5555"


def add_serve(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane serve`."""
    parser = subparsers.add_parser(
        "serve",
        help="serve scenes over ZeroMQ",
        description=(
            "Load scenes (built-in names or TOML files), build their evaluators, bind, and "
            "answer queries until SIGTERM or SIGINT. Prints the bound address on one line."
        ),
    )
    parser.add_argument(
        "--scene",
        action="append",
        metavar="NAME|FILE",
        help="scene to host (repeat for several; default: membrane)",
    )
    parser.add_argument(
        "--bind",
        default=DEFAULT_BIND,
        metavar="ADDR",
        help=f"ZeroMQ endpoint (default {DEFAULT_BIND}; tcp://127.0.0.1:* picks a free port)",
    )
    parser.add_argument(
        "--threads", type=int, default=1, help="onnxruntime intra-op threads (default 1)"
    )
    parser.add_argument(
        "--daemon",
        action="store_true",
        help="detach and run in the background; returns once the server answers",
    )
    parser.add_argument(
        "--pidfile", metavar="FILE", help="with --daemon: pidfile, locked while the server runs"
    )
    parser.add_argument("--logfile", metavar="FILE", help="with --daemon: append logs here")
    parser.set_defaults(handler=_run_serve)


def _run_serve(args: argparse.Namespace) -> int:
    from membrane_client.commands import UsageError

    if args.threads < 1:
        raise UsageError(f"--threads must be >= 1, got {args.threads}")
    if (args.pidfile or args.logfile) and not args.daemon:
        raise UsageError("--pidfile and --logfile go with --daemon")
    scenes = args.scene or ["membrane"]
    if not args.daemon:
        return _serve(scenes, args.bind, args.threads, notify_ready=None)
    return _serve_detached(scenes, args)


def _serve(
    scenes: list[str], bind: str, threads: int, notify_ready: Callable[[str], None] | None
) -> int:
    from membrane_server.server import Server

    server = Server(scenes, bind=bind, threads=threads)
    server.install_signal_handlers()

    def announce(address: str) -> None:
        names = ", ".join(server.scene_names)
        print(f"membrane serve: listening on {address} (scenes: {names})", flush=True)
        if notify_ready is not None:
            notify_ready(address)

    server.serve_forever(on_bound=announce)
    print("membrane serve: stopped", file=sys.stderr, flush=True)
    return 0


def _serve_detached(scenes: list[str], args: argparse.Namespace) -> int:
    from membrane_client.commands import UsageError
    from membrane_server.daemon import AlreadyRunning, run_detached
    from membrane_server.scene import load_scene

    for scene in scenes:  # scene files are checked here, where the user can see the error
        load_scene(scene)
    try:
        code = run_detached(
            lambda notify: _serve(scenes, args.bind, args.threads, notify),
            pidfile=args.pidfile,
            logfile=args.logfile,
        )
    except AlreadyRunning as exc:
        raise UsageError(str(exc)) from None
    if code == 0:
        print(f"membrane serve: daemon started (pidfile {args.pidfile or 'none'})", flush=True)
    else:
        print("membrane serve: the daemon failed to start", file=sys.stderr, flush=True)
    return code
