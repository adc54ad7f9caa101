"""`membrane serve`: load scenes, bind, answer until SIGTERM/SIGINT.

Imports here are the core dependencies only; the server (onnxruntime, pydantic, scipy) is
imported by the handler, so a client-only install still lists the command.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from membrane_cli.arguments import bounded_float, bounded_int
from membrane_client.client import DEFAULT_ADDRESS as DEFAULT_BIND
from membrane_client.protocol import MAX_BATCH_STEPS

if TYPE_CHECKING:  # annotations only: importing these at run time is the handler's job
    import zmq

    from membrane_server.security import CurveAuthenticator
    from membrane_server.server import Server

__all__ = ["add_serve"]

logger = logging.getLogger(__name__)


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
        "--peer-budget",
        type=int,
        default=None,
        metavar="BYTES",
        help="bytes of unread replies kept per client before further ones are dropped "
        "(default 1 MiB; docs/ROBUSTNESS.md)",
    )
    parser.add_argument(
        "--spin-us",
        type=float,
        default=0.0,
        metavar="US",
        help="after each reply, poll without sleeping for this long (up to 100000): faster "
        "replies at haptic rates, for a core while clients are active (default 0)",
    )
    parser.add_argument(
        "--max-batch",
        type=bounded_int(1, MAX_BATCH_STEPS),
        default=MAX_BATCH_STEPS,
        metavar="N",
        help=f"answer up to N queued requests together, their steps of loads stepped as one "
        f"operation (default {MAX_BATCH_STEPS}; 1: each alone, no reply waits for the others')",
    )
    parser.add_argument(
        "--blas-threads",
        type=bounded_int(1, 1024),
        default=1,
        metavar="N",
        help="threads numpy's BLAS may use for a frame (default 1: the steadiest latency when "
        "cores are shared)",
    )
    parser.add_argument(
        "--max-sessions",
        type=bounded_int(1, 100_000),
        default=64,
        metavar="N",
        help="live sessions open at once; more get too_many_sessions (default 64)",
    )
    parser.add_argument(
        "--max-sessions-per-peer",
        type=bounded_int(1, 100_000),
        default=None,
        metavar="N",
        help="live sessions one peer (a connection; with CurveZMQ, a key) may hold at once "
        "(default 16); many connections without keys can still fill --max-sessions: keys are "
        "the defence",
    )
    parser.add_argument(
        "--session-idle-s",
        type=bounded_float(0, exclusive=True),
        default=300.0,
        metavar="S",
        help="a live session unused this long is closed (default 300)",
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
    parser.add_argument(
        "--curve-secret",
        metavar="FILE",
        help="CurveZMQ: the server's .key_secret file (encrypt; with --curve-clients)",
    )
    parser.add_argument(
        "--curve-clients",
        metavar="DIR",
        help="CurveZMQ: directory of the allowed clients' public .key files",
    )
    parser.add_argument(
        "--workers",
        type=_worker_count,
        default=1,
        metavar="N|auto",
        help="worker processes, each with its own sessions, on --bind's port and the N - 1 "
        "after it (auto: one per core; default 1); clients hash sessions over them "
        "(membrane_client.workers; docs/OPERATIONS.md)",
    )
    parser.add_argument(
        "--worker-list",
        metavar="ADDR,ADDR,...",
        type=_endpoint_list,
        default=(),
        help="every worker's endpoint as clients reach it, which hello lists (default with "
        "--workers: the workers' own; in a container or across machines, the names clients "
        "use, e.g. one per pod of a StatefulSet)",
    )
    parser.set_defaults(handler=_run_serve)


def _endpoint_list(text: str) -> tuple[str, ...]:
    """``--worker-list``'s endpoints, in order (each checked as --bind is, before serving)."""
    return tuple(text.split(","))


def _worker_count(text: str) -> int:
    if text == "auto":
        return os.cpu_count() or 1
    return bounded_int(1, 256)(text)


def _run_serve(args: argparse.Namespace) -> int:
    from membrane_cli.arguments import UsageError

    if args.threads < 1:
        raise UsageError(f"--threads must be >= 1, got {args.threads}")
    if args.peer_budget is not None and args.peer_budget < 1:
        raise UsageError(f"--peer-budget must be a positive byte count, got {args.peer_budget}")
    if not 0.0 <= args.spin_us <= 100_000.0:
        raise UsageError(f"--spin-us must be between 0 and 100000, got {args.spin_us:g}")
    if (args.pidfile or args.logfile) and not args.daemon:
        raise UsageError("--pidfile and --logfile go with --daemon")
    if (args.curve_secret is None) != (args.curve_clients is None):
        raise UsageError("--curve-secret and --curve-clients go together")
    _check_endpoint(args.bind)  # before the CurveZMQ warning, which would misread a bad one
    for endpoint in args.worker_list:
        _check_endpoint(endpoint, "--worker-list")
    _check_curve_keys(args)  # before detaching, so that a bad key is reported here
    _make_paths_absolute(args)
    scenes = args.scene or ["membrane"]
    if args.workers > 1:
        return _serve_workers(scenes, args)
    if not args.daemon:
        return _serve(scenes, args, notify_ready=None)
    return _serve_detached(scenes, args)


def _serve_workers(scenes: list[str], args: argparse.Namespace) -> int:
    """``--workers N``: N `membrane serve` processes with these options (``workers``)."""
    from membrane_cli.arguments import UsageError
    from membrane_server.workers import run_workers, worker_endpoints

    endpoints = worker_endpoints(args.bind, args.workers)
    advertised = list(args.worker_list) or endpoints
    if len(advertised) != len(endpoints):
        raise UsageError(
            f"--worker-list names {len(advertised)} workers, --workers {len(endpoints)}"
        )
    argv = [item for scene in scenes for item in ("--scene", scene)]
    for flag, value in (
        ("--threads", args.threads), ("--peer-budget", args.peer_budget),
        ("--spin-us", args.spin_us), ("--blas-threads", args.blas_threads),
        ("--max-batch", args.max_batch),
        ("--max-sessions", args.max_sessions),
        ("--max-sessions-per-peer", args.max_sessions_per_peer),
        ("--session-idle-s", args.session_idle_s), ("--curve-secret", args.curve_secret),
        ("--curve-clients", args.curve_clients),
    ):  # fmt: skip
        if value is not None:
            argv += [flag, str(value)]
    if args.daemon:  # the daemon is the workers' parent: SIGTERM to its pid stops them all
        return _detached(
            scenes, args, lambda ready: run_workers(argv, endpoints, advertised, ready)
        )
    return run_workers(argv, endpoints, advertised)


def _check_endpoint(bind: str, option: str = "--bind") -> None:
    """Refuse a --bind (or ``option``) that ZeroMQ would only answer with "Invalid argument".

    The usual slip is a bare host:port, which needs its transport: tcp://127.0.0.1:5555.
    """
    from membrane_cli.arguments import UsageError

    transport, sep, rest = bind.partition("://")
    if not sep:
        example = f"tcp://{bind or '127.0.0.1:5555'}"
        raise UsageError(
            f"{option} needs a ZeroMQ endpoint with its transport, e.g. {example}; got {bind!r}"
        )
    if transport == "ipc" and rest:
        return
    if transport != "tcp":
        raise UsageError(f"{option}: use a tcp:// (or ipc://) endpoint, got {bind!r}")
    host, colon, port = rest.rpartition(":")
    # ZeroMQ itself takes port 99999 without a word (and binds some other port).
    if not colon or not host or not (port == "*" or (port.isdigit() and int(port) < 65536)):
        raise UsageError(
            f"{option}: a tcp endpoint is tcp://HOST:PORT (PORT up to 65535; * or 0 for a free "
            f"one), e.g. tcp://127.0.0.1:5555; got {bind!r}"
        )


def _make_paths_absolute(args: argparse.Namespace) -> None:
    """Resolve file arguments against the current directory: a daemon runs from /."""
    from pathlib import Path

    def absolute(text: str) -> str:
        path = Path(text)
        is_file = path.suffix == ".toml" or "/" in text or path.is_file()  # as load_scene
        return str(path.resolve()) if is_file else text  # a built-in scene name stays

    if args.scene:
        args.scene = [absolute(scene) for scene in args.scene]
    for name in ("curve_secret", "curve_clients"):
        if getattr(args, name) is not None:
            setattr(args, name, str(Path(getattr(args, name)).resolve()))


def _check_curve_keys(args: argparse.Namespace) -> None:
    if args.curve_secret is None:
        return
    from membrane_server.security import CurveAuthenticator, server_socket_options

    server_socket_options(args.curve_secret)
    CurveAuthenticator(args.curve_clients)  # checks the directory; starts nothing


def _serve(
    scenes: list[str], args: argparse.Namespace, notify_ready: Callable[[str], None] | None
) -> int:
    import zmq
    from threadpoolctl import threadpool_limits

    from membrane_server import log_output
    from membrane_server.server import (
        DEFAULT_PEER_BUDGET,
        SHUTDOWN_LINGER_MS,
        Server,
        raise_open_file_limit,
    )
    from membrane_server.sessions import DEFAULT_MAX_PER_PEER, SessionTable

    threadpool_limits(limits=args.blas_threads, user_api="blas")  # for the process's lifetime
    before, after = raise_open_file_limit()  # each client costs a descriptor
    if after != before:
        logger.info("open-file limit raised from %d to %d", before, after)

    # A context of our own, created here (after any fork) and terminated at the end: terminating
    # it is what lets the last replies leave before the process exits.
    context: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    authenticator: CurveAuthenticator | None = None
    output: log_output.LogOutput | None = None
    try:
        options, authenticator = _secure(args, context)
        server = Server(
            scenes,
            bind=args.bind,
            workers=args.worker_list,
            threads=args.threads,
            context=context,
            socket_options=options,
            peer_budget=args.peer_budget or DEFAULT_PEER_BUDGET,
            spin=args.spin_us / 1e6,
            max_batch=args.max_batch,
            sessions=SessionTable(
                args.max_sessions,
                args.session_idle_s,
                max_per_peer=args.max_sessions_per_peer or DEFAULT_MAX_PER_PEER,
            ),
        )
        # The scenes load: serving starts. Logging from here on neither blocks serving (a
        # stderr pipe nobody reads) nor floods (where stderr has no descriptor: as it was).
        output = log_output.installed() or log_output.install(sys.stderr)
        _warn_invisible_motion(server)
        server.install_signal_handlers()

        def announce(address: str) -> None:
            names = ", ".join(server.scene_names)
            secured = ", CurveZMQ" if authenticator is not None else ""
            print(f"membrane serve: listening on {address} (scenes: {names}{secured})", flush=True)
            if notify_ready is not None:
                notify_ready(address)

        server.serve_forever(on_bound=announce)
    finally:
        if authenticator is not None:
            authenticator.stop()
        context.destroy(linger=SHUTDOWN_LINGER_MS)
    if output is None:
        print("membrane serve: stopped", file=sys.stderr, flush=True)
    else:
        output.write_text("membrane serve: stopped")  # through the queue: stderr may be full
        output.drain(SHUTDOWN_LINGER_MS / 1000)
    return 0


def _warn_invisible_motion(server: Server) -> None:
    """A scene whose spheres would not visibly move is served, with a warning: a first scene
    file left at placement.scale = 1 looks like a server that sends nothing."""
    from membrane_server.visibility import invisible_motion

    for served in server.dispatcher.scenes.values():
        warning = invisible_motion(served.scene, served.evaluator)
        if warning is not None:
            logger.warning("%s", warning)


def _secure(
    args: argparse.Namespace, context: zmq.Context[zmq.Socket[bytes]]
) -> tuple[dict[int, int | bytes], CurveAuthenticator | None]:
    """CurveZMQ socket options and a started authenticator, or none (with a warning when the
    bind reaches beyond this machine)."""
    from membrane_server.security import (
        CurveAuthenticator,
        is_loopback_endpoint,
        server_socket_options,
    )

    if args.curve_secret is None:
        if not is_loopback_endpoint(args.bind):
            logger.warning(
                "serving %s without CurveZMQ: anyone who can reach it can query "
                "(see --curve-secret, --curve-clients)",
                args.bind,
            )
        return {}, None
    options = server_socket_options(args.curve_secret)
    authenticator = CurveAuthenticator(args.curve_clients, context)
    authenticator.start()
    return options, authenticator


def _serve_detached(scenes: list[str], args: argparse.Namespace) -> int:
    return _detached(scenes, args, lambda notify: _serve(scenes, args, notify))


def _detached(
    scenes: list[str], args: argparse.Namespace, main: Callable[[Callable[[str], None]], int]
) -> int:
    """``main(notify_ready)`` as a daemon (``daemon.run_detached``), once the scenes load."""
    from membrane_cli.arguments import UsageError
    from membrane_server.daemon import AlreadyRunning, run_detached
    from membrane_server.scene import load_scene

    for scene in scenes:  # scene files are checked here, where the user can see the error
        load_scene(scene)
    try:
        code = run_detached(main, pidfile=args.pidfile, logfile=args.logfile)
    except AlreadyRunning as exc:
        raise UsageError(str(exc)) from None
    if code == 0:
        print(f"membrane serve: daemon started (pidfile {args.pidfile or 'none'})", flush=True)
    else:
        print("membrane serve: the daemon failed to start", file=sys.stderr, flush=True)
    return code
