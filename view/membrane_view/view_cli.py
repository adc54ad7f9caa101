"""`membrane view` (the scene in a browser) and `membrane animate` (a GIF or an MP4).

This module imports with the core dependencies only; aiohttp and matplotlib (the ``view`` extra)
are imported when a command runs.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import sys
from pathlib import Path

from membrane_cli.arguments import UsageError, bounded_float, bounded_int
from membrane_cli.connection import add_connection_arguments, connect, curve_options
from membrane_errors import MembraneError

__all__ = ["add_animate", "add_view"]

POSITIVE = bounded_float(0.0, exclusive=True)
PORT = bounded_int(0, 65535, why="a TCP port")
CONNECTIONS = bounded_int(1, 64, why="pages held at once, each with its own session")
EXTRA_HINT = "pip install 'membrane-tissue[view]'"
TOKEN_ENV = "MEMBRANE_VIEW_TOKEN"  # a fixed token: a bookmarked address survives a restart
TOKEN_CHARS = re.compile(r"[A-Za-z0-9_.~-]{16,256}")


def add_view(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane view`."""
    parser = subparsers.add_parser(
        "view",
        help="see a scene in a browser, and press on a live one with the mouse",
        description=(
            "Serve a local web page that shows a scene: a film scene plays at its dt, a live "
            "scene is stepped at one step per dt of wall-clock time (times --speed) and a "
            "pointer press on the page drives a probe (depth from a slider). The page talks to "
            "this bridge over a WebSocket; the bridge is a membrane client (docs/VIEW.md). "
            "Only its own address is answered (Host and Origin checked), and the page needs "
            "the token in the address printed at start (a new one each run, or "
            f"${TOKEN_ENV}: 16 to 256 URL-safe characters)."
        ),
    )
    add_connection_arguments(parser)
    parser.add_argument("--scene", metavar="NAME", help="scene to show (needed with several)")
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        metavar="IP",
        help="address the page is served on (default 127.0.0.1)",
    )
    parser.add_argument(
        "--port",
        type=PORT,
        default=8765,
        metavar="P",
        help="port of the page (default 8765; 0 picks a free one)",
    )
    parser.add_argument(
        "--speed",
        type=POSITIVE,
        default=1.0,
        metavar="X",
        help="simulation seconds per wall-clock second (default 1)",
    )
    parser.add_argument(
        "--fps",
        type=POSITIVE,
        default=60.0,
        metavar="N",
        help="frames pushed to the page per second at most (default 60)",
    )
    parser.add_argument(
        "--max-connections",
        type=CONNECTIONS,
        default=8,
        metavar="N",
        help="pages (WebSockets) served at once, each with its own session; more get 503 "
        "(default 8)",
    )
    parser.set_defaults(handler=_run_view)


def add_animate(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `membrane animate`."""
    parser = subparsers.add_parser(
        "animate",
        help="write a scene's animation (a film, or a scripted poke on a live scene) to GIF/MP4",
        description=(
            "Animate a scene with matplotlib: a film scene's frames, or on a live scene a probe "
            "at the centre that presses for 0.4 s and lets go (the tissue then rings). GIF "
            "through Pillow; MP4 through ffmpeg when it is on the PATH."
        ),
    )
    add_connection_arguments(parser)
    parser.add_argument("--scene", metavar="NAME", required=True, help="scene to animate")
    parser.add_argument("--out", metavar="FILE", required=True, help="FILE.gif or FILE.mp4")
    parser.add_argument(
        "--fps",
        type=POSITIVE,
        default=20.0,
        metavar="N",
        help="frames per second of the animation (default 20)",
    )
    parser.add_argument(
        "--speed",
        type=POSITIVE,
        default=0.5,
        metavar="X",
        help="simulation seconds per second of animation (default 0.5)",
    )
    parser.add_argument(
        "--depth",
        type=bounded_float(0.0),
        default=0.01,
        metavar="D",
        help="a live scene's probe depth, problem units (default 0.01)",
    )
    parser.set_defaults(handler=_run_animate)


def _needs_extra(exc: ModuleNotFoundError) -> MembraneError:
    return MembraneError(f"needs the 'view' extra: {EXTRA_HINT} ({exc.name} is missing)")


def _run_view(args: argparse.Namespace) -> int:
    try:
        ipaddress.ip_address(args.host)
    except ValueError:
        raise UsageError(f"--host must be an IP address, got {args.host!r}") from None
    token = os.environ.get(TOKEN_ENV)
    if token is not None and not TOKEN_CHARS.fullmatch(token):
        raise UsageError(f"${TOKEN_ENV} must be 16 to 256 URL-safe characters (A-Z a-z 0-9 _.~-)")
    try:
        from aiohttp import web

        from membrane_view.bridge import BridgeConfig, make_app
        from membrane_view.guard import new_token
    except ModuleNotFoundError as exc:
        raise _needs_extra(exc) from None
    config = BridgeConfig(
        connect=args.connect,
        scene=args.scene,
        timeout=args.timeout,
        speed=args.speed,
        fps=args.fps,
        socket_options=curve_options(args),
        token=token or new_token(),
        max_connections=args.max_connections,
    )
    try:
        web.run_app(
            make_app(config),
            host=args.host,
            port=args.port,
            print=lambda text: _announce(text, args.connect, config.token),
        )
    except OSError as exc:
        raise UsageError(f"cannot serve on {args.host}:{args.port}: {exc.strerror}") from None
    return 0


def _announce(text: str, connect: str, token: str) -> None:
    """aiohttp's "Running on URL" as one line (with the port a --port 0 picked), each address
    with the token the page needs, as Jupyter prints it."""
    urls = [url if url.endswith("/") else url + "/" for url in re.findall(r"http://\S+", text)]
    # On every interface: the loopback address is one the Host check accepts (0.0.0.0 is not).
    urls = [url.replace("//0.0.0.0:", "//127.0.0.1:") for url in urls]
    where = ", ".join(f"{url}?token={token}" for url in urls) or text.strip()
    print(f"membrane view: {where} (server {connect}); Ctrl-C stops", file=sys.stderr, flush=True)


def _run_animate(args: argparse.Namespace) -> int:
    out = Path(args.out)
    try:
        from membrane_view.animate import check_output, film_clip, poke_clip, write_clip

        writer = check_output(out)
    except ModuleNotFoundError as exc:
        raise _needs_extra(exc) from None
    with connect(args, scene=args.scene) as client:
        info = client.describe(args.scene)
        if info.live:
            clip = poke_clip(client, args.scene, args.fps, args.speed, args.depth)
        else:
            clip = film_clip(client, args.scene, args.fps, args.speed)
    count = write_clip(clip, out, writer, args.fps)
    print(f"{out}: {count} frames of {info.name} at {args.fps:g} fps", file=sys.stderr)
    return 0
