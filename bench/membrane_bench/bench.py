"""One benchmark as `membrane bench` runs it: probe the server, load it, load the echo, compare.

``probe`` asks the server what to send (the scene's time grid) and how long its replies are;
``run_bench`` runs the load against the server and, for a baseline, the same load from the same
code against an echo server (``membrane_bench.echo``) whose replies are as long; ``BenchReport``
holds both and renders them as a table, JSON or CSV rows.

Every ``vs_baseline`` figure reads "how many times worse than the echo": a latency percentile is
server / echo, throughput is echo / server. 1.0 means the server costs nothing beyond ZeroMQ.
"""

from __future__ import annotations

import contextlib
import csv
import math
import secrets
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from membrane_bench.echo import EchoServer
from membrane_bench.loadtest import (
    PERCENTILES,
    STEP_DEPTH,
    STEP_RADIUS,
    LoadResult,
    LoadSpec,
    ProgressHook,
    run_load,
)
from membrane_client.client import Client
from membrane_client.errors import MembraneError, Timeout, UserError
from membrane_client.frame import SceneInfo
from membrane_client.live_schema import Probe, Tool
from membrane_client.protocol import Op, encode
from membrane_client.session import Session

__all__ = ["BenchError", "BenchReport", "Target", "probe", "run_bench"]

_LATENCY_COLUMNS = (*PERCENTILES, "max")
_CSV_COUNTS = (
    "sent",
    "replies",
    "ok",
    "error_count",
    "missed_deadlines",
    "unsent",
    "throughput_hz",
)


class BenchError(MembraneError):
    """The server under test cannot be benchmarked (no reply, or an error reply to the probe)."""


@dataclass(frozen=True)
class Target:
    """What the probe learnt about the server under test.

    Attributes:
        address: The server's address.
        scene: The scene the queries go to (as the server names it), or None for ``ping``.
        times: The query times to cycle through (the scene's step times, or the one asked for).
        reply_bytes: Length of the server's reply to one benchmarked request.
        evaluator: The scene's evaluator kind (``describe``; "live" for live steps), or None.
        probe_at: Where a live step's probe presses (the middle of the scene's domain).
        probe_radius: Its footprint's radius (a physical scene's first table radius), or the
            tool's.
        press: "probe", or "tool" where the scene's engine takes rigid tools only.
    """

    address: str
    scene: str | None
    times: tuple[float, ...]
    reply_bytes: int
    evaluator: str | None
    probe_at: tuple[float, ...] = (0.5, 0.5)
    probe_radius: float = STEP_RADIUS
    press: str = "probe"


def probe(
    address: str,
    payload: str = "query",
    scene: str | None = None,
    fixed_t: float | None = None,
    timeout: float = 2.0,
) -> Target:
    """Ask the server for its time grid and measure its reply to one benchmarked request.

    Raises:
        BenchError: No reply within ``timeout``, or an error reply (e.g. an unknown scene).
    """
    op = payload
    try:
        with Client(address, timeout=timeout, scene=scene) as client:
            if payload == "ping":
                return Target(address, None, (0.0,), _reply_bytes(client.request(Op.PING)), None)
            op = Op.DESCRIBE
            info = client.describe()
            if payload in ("step", "step-frames"):
                op = Op.STEP
                return _probe_live(client, info, payload == "step-frames")
            times = (fixed_t,) if fixed_t is not None else tuple(float(t) for t in info.times())
            op = Op.QUERY
            reply = client.request(Op.QUERY, scene=scene, t=times[0])
    except Timeout:
        raise BenchError(
            f"no reply from {address} within {timeout:g} s (is a server there?)"
        ) from None
    except UserError:
        raise  # a malformed address: bad input, not the server's failure
    except MembraneError as exc:
        raise BenchError(f"{op} request to {address} failed: {exc}") from None
    return Target(address, info.name, times, _reply_bytes(reply), info.evaluator)


def _probe_live(client: Client, info: SceneInfo, frames: bool) -> Target:
    """A live scene's target: one step with the load's probe, in a session of its own."""
    if not info.live:
        raise BenchError(f"scene {info.name} is not live: --payload step needs a live scene")
    centre, radius = _probe_place(info)
    inputs = info.live.get("inputs", ["probes"])
    press = "tool" if "probes" not in inputs and "tools" in inputs else "probe"
    if press == "tool":  # a sphere a tenth of the domain across: 5 mm on the skin patch
        extent = info.points.max(axis=0) - info.points.min(axis=0)
        radius = float(extent.max()) / 10
        pressing = {"tools": [Tool("sphere", centre, STEP_DEPTH, radius).to_wire()]}
    else:
        pressing = {"probes": [Probe(centre, STEP_DEPTH, radius).to_wire()]}
    with Session(client, info.name).open() as session:
        reply = client.request(
            Op.STEP, scene=info.name, session=session.id, k=0, frame=frames, **pressing
        )
    return Target(client.address, info.name, (0.0,), _reply_bytes(reply), "live", centre,
                  radius, press)  # fmt: skip


def _probe_place(info: SceneInfo) -> tuple[tuple[float, ...], float]:
    """The middle of the scene's domain and a radius its engine carries: a physical scene's
    extent (m) and first footprint radius, else the unit domain's middle and 0.05."""
    if info.declared_extent is not None:  # a physical scene (in m)
        lower, upper = info.points.min(axis=0), info.points.max(axis=0)
        centre = tuple(float(a + b) / 2 for a, b in zip(lower, upper, strict=True))
        radii = info.live.get("radii")
        return centre, float(radii[0]) if isinstance(radii, list) else STEP_RADIUS
    return tuple(0.5 for _ in range(info.points.shape[1])), STEP_RADIUS


def _reply_bytes(reply: dict[str, Any]) -> int:
    """A reply's length on the wire: encoding the decoded reply again gives the same bytes."""
    return len(encode(reply))


@dataclass
class BenchReport:
    """The server's result, the echo's (with ``--baseline``), and what was asked."""

    target: Target
    spec: LoadSpec
    server: LoadResult
    baseline: LoadResult | None = None
    segments: int = 1

    def vs_baseline(self) -> dict[str, float] | None:
        """Server / echo per latency percentile, echo / server for throughput; None without one."""
        if self.baseline is None:
            return None
        ours, echo = self.server.percentiles(), self.baseline.percentiles()
        ratios = {label: _ratio(ours[label], echo[label]) for label in _LATENCY_COLUMNS}
        ratios["throughput"] = _ratio(self.baseline.throughput, self.server.throughput)
        return ratios

    def config(self) -> dict[str, Any]:
        """The load and the target, as plain data."""
        spec = self.spec
        return {
            "address": self.target.address,
            "scene": self.target.scene,
            "evaluator": self.target.evaluator,
            "mode": spec.mode,
            "rate_hz": spec.rate if spec.mode == "open" else None,
            "concurrency": spec.concurrency if spec.mode == "closed" else None,
            "clients": spec.clients,
            "duration_s": spec.duration,
            "warmup_s": spec.warmup,
            "payload": spec.payload,
            "query_times": len(spec.times) if spec.payload == "query" else 0,
            "reply_bytes": self.target.reply_bytes,
            "timeout_s": spec.timeout,
            "deadline_ms": None if spec.deadline_s is None else spec.deadline_s * 1e3,
            "segments": self.segments,
        }

    def to_dict(self) -> dict[str, Any]:
        """Everything, for ``--json``."""
        return {
            "config": self.config(),
            "server": self.server.summary(),
            "baseline": None if self.baseline is None else self.baseline.summary(),
            "vs_baseline": self.vs_baseline(),
        }

    def table(self) -> str:
        """A fixed-width table for people."""
        lines = [self._headline(), ""]
        header = f"{'':<16}" + "".join(f"{c:>10}" for c in _LATENCY_COLUMNS)
        lines.append(header + f"{'req/s':>11}{'errors':>8}{'missed':>8}")
        for result in (self.server, self.baseline):
            if result is not None:
                lines.append(_result_row(result))
        ratios = self.vs_baseline()
        if ratios is not None:
            cells = "".join(f"{_times(ratios[c]):>10}" for c in _LATENCY_COLUMNS)
            lines.append(f"{'server vs echo':<16}{cells}{_times(ratios['throughput']):>11}")
            lines.append("(latency: server / echo; req/s: echo / server; 1.00x: as fast as ZeroMQ)")
        for result in (self.server, self.baseline):
            if result is not None and result.unsent:
                lines.append(
                    f"{result.label}: {result.unsent} requests fell due but were not sent before "
                    "the end: it could not keep up with the rate"
                )
        if self.spec.mode == "open":
            lines.append(
                "latency counts from each request's due time (coordinated omission corrected); "
                f"missed = later than {self.spec.deadline_s * 1e3:g} ms"  # type: ignore[operator]
            )
        return "\n".join(lines)

    def _headline(self) -> str:
        spec = self.spec
        load = (
            f"open loop {spec.rate:g} Hz"
            if spec.mode == "open"
            else (f"closed loop {spec.concurrency} in flight")
        )
        clients = f"{spec.clients} client{'s' if spec.clients > 1 else ''}"
        what: str = spec.payload
        if spec.payload == "query":
            what += f" on scene {self.target.scene} ({self.target.evaluator or '?'} evaluator)"
        timing = f"{spec.duration:g} s (+{spec.warmup:g} s warm-up)"
        if self.segments > 1:
            timing = (
                f"{spec.duration:g} s in {self.segments} parts alternating with the echo "
                f"(+{spec.warmup:g} s warm-up each)"
            )
        return (
            f"{load}, {clients}, {timing}, {what}, "
            f"{self.target.reply_bytes}-byte replies, {self.target.address}"
        )

    def csv_rows(self) -> list[dict[str, Any]]:
        """One row per run (server, then echo); the server row carries the ratios."""
        config = self.config()
        ratios = self.vs_baseline() or {}
        rows = []
        for result in (self.server, self.baseline):
            if result is None:
                continue
            summary = result.summary()
            row: dict[str, Any] = {"label": result.label, **config, "address": result.address}
            for key in _CSV_COUNTS:
                row[key] = summary[key]
            row["errors"] = ";".join(f"{k}={v}" for k, v in summary["errors"].items())
            for name, value in summary["latency_us"].items():
                row[f"{name}_us"] = value
            for name, value in summary["service_us"].items():
                row[f"service_{name}_us"] = value
            for name in (*_LATENCY_COLUMNS, "throughput"):
                is_server = result is self.server
                row[f"{name}_vs_baseline"] = ratios.get(name) if is_server else None
            rows.append(row)
        return rows

    def write_csv(self, path: Path) -> None:
        """Append the rows to ``path`` (header written when the file is new or empty)."""
        rows = self.csv_rows()
        new = not path.exists() or path.stat().st_size == 0
        with path.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            if new:
                writer.writeheader()
            writer.writerows(rows)


def _ratio(numerator: float, denominator: float) -> float:
    if not (denominator > 0 and math.isfinite(numerator)):
        return math.nan
    return numerator / denominator


def _times(ratio: float) -> str:
    return "-" if math.isnan(ratio) else f"{ratio:.2f}x"


def _result_row(result: LoadResult) -> str:
    values = result.percentiles()
    cells = "".join(f"{_us(values[c]):>10}" for c in _LATENCY_COLUMNS)
    missed = "-" if result.missed_deadlines is None else str(result.missed_deadlines)
    errors = sum(result.errors.values())
    return f"{result.label + ' (us)':<16}{cells}{result.throughput:>11.1f}{errors:>8}{missed:>8}"


def _us(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.0f}"


def run_bench(
    target: Target,
    spec: LoadSpec,
    baseline: bool = False,
    progress: Callable[[str, LoadSpec], ProgressHook | None] | None = None,
    segments: int = 1,
) -> BenchReport:
    """Load the server and (``baseline``) the echo with the same spec; returns both.

    Args:
        target: From ``probe``; its times replace ``spec.times`` for a query load.
        spec: The load.
        baseline: Also run the echo baseline.
        progress: Given a run's label and spec, returns the hook to call while it runs.
        segments: Split the run into this many parts, alternating server and echo (each part
            ``spec.duration / segments`` long, with its own warm-up), so that a background load
            that changes during the run weighs on both alike. Percentiles merge exactly (HDR).
    """
    if segments < 1:
        raise BenchError(f"segments must be >= 1, got {segments}")
    if spec.payload == "query":
        spec = replace(spec, times=target.times, scene=target.scene)
    elif spec.payload in ("step", "step-frames"):
        spec = replace(
            spec,
            scene=target.scene,
            probe_at=target.probe_at,
            probe_radius=target.probe_radius,
            press=target.press,
        )
    session = secrets.token_hex(16)  # bench clients identify themselves as a real client does
    spec = replace(spec, session=session)
    part = replace(spec, duration=spec.duration / segments)

    def hook(label: str, index: int) -> ProgressHook | None:
        tag = f" {index + 1}/{segments}" if segments > 1 else ""
        return progress(label + tag, part) if progress else None

    servers: list[LoadResult] = []
    echoes: list[LoadResult] = []
    with contextlib.ExitStack() as stack:
        echo = (
            stack.enter_context(EchoServer(target.address, target.reply_bytes))
            if baseline
            else None
        )
        for index in range(segments):
            servers.append(run_load(target.address, part, "server", hook("server", index)))
            if echo is not None:
                echoes.append(run_load(echo.address, part, "echo", hook("echo", index)))
    return BenchReport(
        target=target,
        spec=spec,
        server=LoadResult.combine(spec, servers),
        baseline=LoadResult.combine(spec, echoes) if echoes else None,
        segments=segments,
    )
