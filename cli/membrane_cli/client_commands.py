"""`membrane query` (one frame, as a summary or JSON), `membrane ping` (a health check) and
`membrane stats` (the server's counters and latency percentiles, for people or as JSON).

Exit codes: 0 answered; 1 no answer (timeout) or a server-side failure; 2 bad input (including
a request the server refuses as bad, such as a NaN time or an unknown scene).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from membrane_cli.connection import add_connection_arguments, connect
from membrane_client.client import Client
from membrane_client.errors import MembraneError, ServerError, UserError
from membrane_client.frame import Frame
from membrane_client.protocol import ErrorCode, Op
from membrane_client.replies import StatsReply

__all__ = ["add_ping", "add_query", "add_stats", "stats_summary"]

if TYPE_CHECKING:  # argparse's class is generic for type checkers only
    Subparsers = argparse._SubParsersAction[argparse.ArgumentParser]

# Error codes that mean "your request was wrong": exit code 2, like any bad input.
_CALLER_ERRORS = {
    ErrorCode.BAD_REQUEST,
    ErrorCode.UNKNOWN_SCENE,
    ErrorCode.INVALID_TIME,
    ErrorCode.OUT_OF_DOMAIN,
}


def add_query(subparsers: Subparsers) -> None:
    """Register `membrane query`."""
    parser = subparsers.add_parser(
        "query",
        help="ask a server for one frame",
        description="Query the frame served for simulation time T and print it.",
    )
    add_connection_arguments(parser)
    parser.add_argument("--scene", help="scene name (needed when the server hosts several)")
    parser.add_argument("--t", type=float, required=True, metavar="T", help="time in seconds")
    parser.add_argument("--json", action="store_true", help="print the whole frame as JSON")
    parser.add_argument(
        "--float64", action="store_true", help="ask for float64 displacements (default float32)"
    )
    parser.set_defaults(handler=_run_query)


def add_ping(subparsers: Subparsers) -> None:
    """Register `membrane ping`."""
    parser = subparsers.add_parser(
        "ping",
        help="check that a server answers (exit 0) or not (exit 1)",
        description="Send one ping; exit 0 when the server answers, 1 otherwise.",
    )
    add_connection_arguments(parser)
    parser.set_defaults(handler=_run_ping)


def add_stats(subparsers: Subparsers) -> None:
    """Register `membrane stats`."""
    parser = subparsers.add_parser(
        "stats",
        help="print a server's counters and latency percentiles",
        description=(
            "Ask a server for its figures since start (the protocol's stats op): requests by op, "
            "scene and error code, sessions, and server-side latency percentiles. Exit 0 when it "
            "answers, 1 otherwise."
        ),
    )
    add_connection_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the reply as JSON")
    parser.set_defaults(handler=_run_stats)


def _run_query(args: argparse.Namespace) -> int:
    try:
        with connect(args, scene=args.scene) as client:
            try:
                frame = client.query(args.t, dtype="<f8" if args.float64 else "<f4")
            except ServerError as exc:
                if exc.code != ErrorCode.UNKNOWN_SCENE:
                    raise
                print(f"membrane query: {_scene_hint(client, args.scene)}", file=sys.stderr)
                return 2
    except UserError:
        raise  # bad input (an address, a key file): the dispatcher's one line, exit 2
    except MembraneError as exc:
        return _report_failure("query", exc)
    print(json.dumps(frame_to_json(frame)) if args.json else frame_summary(frame))
    return 0


def _scene_hint(client: Client, scene: str | None) -> str:
    """What to do about an unknown_scene reply, in the command line's terms: the server's own
    message names the wire field ('scene'); here the fix is the --scene flag."""
    try:
        hosted = ", ".join(client.hello().scenes)
    except MembraneError:
        hosted = "?"  # the server stopped answering; the hint still says what to pass
    if scene is None:
        return f"the server hosts several scenes ({hosted}): pass --scene NAME"
    return f"no scene {scene!r} on the server: pass --scene with one of: {hosted}"


def _run_ping(args: argparse.Namespace) -> int:
    try:
        with connect(args) as client:
            seconds = client.ping()
            hello = client.hello()
    except UserError:
        raise  # bad input (an address, a key file): the dispatcher's one line, exit 2
    except MembraneError as exc:
        print(f"membrane ping: {args.connect}: {_one_line(exc)}", file=sys.stderr)
        return 1
    scenes = ", ".join(hello.scenes)
    print(
        f"pong from {args.connect} in {seconds * 1e3:.3f} ms "
        f"({hello.server}, protocol {hello.protocol}, scenes: {scenes})"
    )
    return 0


def _run_stats(args: argparse.Namespace) -> int:
    try:
        with connect(args) as client:
            stats = client.request(Op.STATS)
            typed = StatsReply.from_reply(stats)
    except UserError:
        raise  # bad input (an address, a key file): the dispatcher's one line, exit 2
    except MembraneError as exc:
        return _report_failure("stats", exc)
    print(json.dumps(stats, indent=2, sort_keys=True) if args.json else stats_summary(typed))
    return 0


def stats_summary(stats: StatsReply | Mapping[str, Any]) -> str:
    """The ``stats`` reply (typed, or its map) as a few lines for people; fields this version
    does not know about are printed as they came, so that a newer server's figures are not
    hidden."""
    reply = stats if isinstance(stats, StatsReply) else StatsReply.from_reply(stats)
    fields = reply.to_reply_fields()  # the figures alone, without the envelope
    known = {"uptime_s", "requests", "sessions", "ops", "scenes", "errors", "latency_us"}
    lines = [
        f"up {_duration(float(reply.uptime_s or 0.0))}, {reply.requests or 0} "
        f"requests, {reply.sessions or 0} sessions",
        f"ops: {_counts(reply.ops)}",
        f"queries by scene: {_counts(reply.scenes)}",
        f"errors: {_counts(reply.errors)}",
        _latency_line(reply.latency_us or {}),
    ]
    for key in sorted(set(fields) - known):
        value = fields[key]
        text = _counts(value) if isinstance(value, dict) else json.dumps(value)
        lines.append(f"{key.replace('_', ' ')}: {text}")
    return "\n".join(lines)


def _counts(counts: Any) -> str:
    """``{"query": 3, "ping": 1}`` -> "query 3, ping 1" (largest first), or "none"."""
    if not counts:
        return "none"
    ordered = sorted(counts.items(), key=lambda item: (-_number(item[1]), str(item[0])))
    return ", ".join(f"{name} {value}" for name, value in ordered)


def _number(value: Any) -> float:
    return float(value) if isinstance(value, int | float) else 0.0


def _latency_line(latency: dict[str, Any]) -> str:
    count, window = latency.get("count", 0), latency.get("window", "?")
    if not count or "p50" not in latency:
        return "latency: no requests yet"
    parts = ", ".join(
        f"{label} {float(latency[key]):.1f}"
        for key, label in (("p50", "p50"), ("p90", "p90"), ("p99", "p99"), ("p999", "p99.9"),
                           ("max", "max"), ("mean", "mean"))
        if key in latency
    )  # fmt: skip
    return f"latency (us, receipt to reply, last {count} of at most {window} requests): {parts}"


def _duration(seconds: float) -> str:
    """Seconds as '3.2 s', '4 min 05 s' or '2 h 03 min'."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(int(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def frame_to_json(frame: Frame) -> dict[str, Any]:
    """A frame as plain JSON data (z as nested lists of floats, shaped like the lattice)."""
    return {
        "scene": frame.scene,
        "t": frame.t,
        "step": frame.step,
        "requested_t": frame.requested_t,
        "domain": frame.domain,
        "shape": list(frame.z.shape),
        "max_abs_z": float(np.abs(frame.z).max()) if frame.z.size else 0.0,
        "z": frame.z.astype(np.float64).tolist(),
    }


def frame_summary(frame: Frame) -> str:
    """A few human-readable lines about a frame."""
    z = frame.z
    lines = [
        f"scene {frame.scene}: step {frame.step}, t = {frame.t:.6g} s "
        f"(requested {frame.requested_t:.6g} s, {frame.domain})"
    ]
    if z.size:
        peak = np.unravel_index(int(np.argmax(np.abs(z))), z.shape)
        where = ", ".join(str(int(i)) for i in peak)
        shape = " x ".join(str(n) for n in z.shape)
        lines.append(
            f"lattice {shape}: max |z| = {float(np.abs(z).max()):.4g} at [{where}], "
            f"mean z = {float(z.mean()):.4g}"
        )
    return "\n".join(lines)


def _report_failure(command: str, exc: MembraneError) -> int:
    print(f"membrane {command}: {_one_line(exc)}", file=sys.stderr)
    return 2 if isinstance(exc, ServerError) and exc.code in _CALLER_ERRORS else 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
