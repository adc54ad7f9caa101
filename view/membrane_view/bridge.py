"""The bridge: a membrane client on one side, a web page on the other (aiohttp).

``GET /`` serves the page (static/, package data), ``GET /ws`` a WebSocket. Per WebSocket the
bridge holds one ``Client`` (used from one worker thread: the client blocks, the event loop must
not) and pushes:

- ``{"type": "scene", ...}`` (JSON text) once described: shape, extent, dt, live or film;
- binary frames (``wire.encode_frame``: a 32-byte header and float32 z) at up to ``fps`` per
  second: a film scene plays at ``speed`` x its dt (frame for simulation time ``elapsed *
  speed``, looping); a live scene is stepped at one step per dt of wall-clock time (times
  ``speed``), the steps due since the last push in one batch, only the last with a frame;
- ``{"type": "stats", ...}`` once a second: the server's counters and percentiles, the bridge's
  own time per frame (encode and send), frames pushed, steps taken and steps dropped (behind);
- ``{"type": "error", "message": ...}`` when the server is unreachable or a session expired; the
  bridge retries once a second and says ``{"type": "status", ...}`` when it is back.

The page sends JSON text: ``{"type": "press", "at": [x, y], "depth": d, "radius": r}`` (lattice
coordinates, problem units) while the pointer is down, ``{"type": "release"}`` when it is up,
and ``{"type": "reset"}``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np
from aiohttp import WSMsgType, web

from membrane_client.client import Client
from membrane_client.curve import SocketOptions
from membrane_client.errors import Timeout
from membrane_client.frame import SceneInfo
from membrane_client.session import Probe, Session
from membrane_errors import MembraneError
from membrane_view.wire import FLAG_CONTACT, FLAG_LIVE, encode_frame

__all__ = ["BridgeConfig", "make_app", "static_dir"]

logger = logging.getLogger(__name__)
T = TypeVar("T")

RETRY_S = 1.0
STATS_EVERY_S = 1.0


def static_dir() -> Path:
    """The page's files (package data)."""
    return Path(str(resources.files("membrane_view") / "static"))


@dataclass
class BridgeConfig:
    connect: str
    scene: str | None = None
    timeout: float = 2.0
    speed: float = 1.0  # simulation seconds per wall-clock second
    fps: float = 60.0  # frames pushed per second at most
    socket_options: SocketOptions | None = None


@dataclass
class Pointer:
    """The page's pointer: a probe while pressed."""

    at: tuple[float, ...] | None = None
    depth: float = 0.0
    radius: float = 0.05
    reset: bool = False

    def probes(self) -> list[Probe]:
        return [] if self.at is None else [Probe(self.at, self.depth, self.radius)]


@dataclass
class Counters:
    frames: int = 0
    steps: int = 0
    dropped_steps: int = 0
    bridge_us: deque[float] = field(default_factory=lambda: deque(maxlen=2000))

    def summary(self) -> dict[str, Any]:
        times = np.asarray(self.bridge_us, dtype=np.float64)
        percentiles = (
            {f"p{q}": float(np.percentile(times, q)) for q in (50, 99)} if times.size else {}
        )
        return {
            "frames": self.frames,
            "steps": self.steps,
            "dropped_steps": self.dropped_steps,
            "bridge_us": percentiles,
        }


def scene_message(info: SceneInfo, config: BridgeConfig) -> dict[str, Any]:
    """What the page needs to draw the scene (JSON)."""
    points = np.asarray(info.points, dtype=np.float64)
    live = bool(info.live)
    lo, hi = points.min(axis=0), points.max(axis=0)
    extent = float(np.max(hi - lo)) if points.size else 1.0
    return {
        "type": "scene",
        "name": info.name,
        "description": info.description,
        "shape": list(info.shape),
        "lo": [float(v) for v in lo],
        "hi": [float(v) for v in hi],
        "dt": info.dt,
        "steps": info.steps,
        "duration": info.duration,
        "live": live,
        "speed": config.speed,
        "fps": config.fps,
        # a probe's depth and radius in problem units: the slider's range
        "depth_max": 0.02 * extent,
        "radius": 0.05 * extent,
        "min_radius": float(info.live.get("min_radius", 0.0)) if live else 0.0,
        # A point list (shape (n,)) is drawn where its points are: a rope along their x, a
        # membrane's points as a scatter. Grids need none (their shape says it all).
        "points": points.tolist() if len(info.shape) == 1 else None,
    }


class Got(NamedTuple):
    """A frame from the server, and when its reply arrived (perf_counter)."""

    k: int
    t: float
    z: np.ndarray
    force: float
    flags: int
    received: float


class Player:
    """One page's connection to the server: films played, live scenes stepped."""

    def __init__(self, config: BridgeConfig, ws: web.WebSocketResponse):
        self.config, self.ws = config, ws
        self.pointer = Pointer()
        self.counters = Counters()
        self.executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="membrane-view")
        self.client: Client | None = None
        self.session: Session | None = None
        self.info: SceneInfo | None = None
        self.last_bridge_us = 0.0
        self.skipped = 0  # steps of wall-clock time not taken (dropped, or before a reset)

    async def call(self, fn: Callable[[], T]) -> T:
        return await asyncio.get_running_loop().run_in_executor(self.executor, fn)

    async def send_json(self, message: dict[str, Any]) -> None:
        await self.ws.send_str(json.dumps(message, allow_nan=False, default=_jsonable))

    def _connect(self) -> SceneInfo:
        if self.client is None:
            self.client = Client(
                self.config.connect,
                timeout=self.config.timeout,
                scene=self.config.scene,
                socket_options=self.config.socket_options,
            )
        info = self.client.describe(self.config.scene, refresh=True)
        if info.live:
            self.session = self.client.session(self.config.scene)
        return info

    def _close(self) -> None:
        if self.session is not None:
            with contextlib.suppress(MembraneError):
                self.session.close()
            self.session = None
        if self.client is not None:
            self.client.close()
            self.client = None

    async def run(self) -> None:
        """Connect (retrying), then push frames until the page goes away."""
        try:
            while not self.ws.closed:
                try:
                    self.info = await self.call(self._connect)
                except MembraneError as exc:
                    await self.send_json({"type": "error", "message": _explain(exc, self.config)})
                    await self.call(self._close)
                    await asyncio.sleep(RETRY_S)
                    continue
                await self.send_json(scene_message(self.info, self.config))
                await self.send_json(
                    {
                        "type": "status",
                        "message": f"connected to {self.config.connect}, scene {self.info.name}",
                    }
                )
                try:
                    await self.play(self.info)
                except MembraneError as exc:
                    if self.ws.closed:
                        break
                    await self.send_json({"type": "error", "message": _explain(exc, self.config)})
                    await self.call(self._close)
                    await asyncio.sleep(RETRY_S)
        except ConnectionResetError:  # the page went away while a message was being sent
            pass
        except Exception as exc:  # a bug: logged with its traceback, and shown on the page
            logger.exception("the bridge failed")
            with contextlib.suppress(Exception):
                await self.send_json({"type": "error", "message": f"the bridge failed: {exc!r}"})
            raise
        finally:
            await self.call(self._close)
            self.executor.shutdown(wait=False)

    async def play(self, info: SceneInfo) -> None:
        period = 1.0 / self.config.fps
        started = time.perf_counter()
        next_push, next_stats = started, started
        self.skipped = 0
        while not self.ws.closed:
            now = time.perf_counter()
            sim_elapsed = (now - started) * self.config.speed
            if info.live:
                got = await self.call(partial(self._steps, info, sim_elapsed, 0.8 * period))
            else:
                got = await self.call(partial(self._film, info, sim_elapsed))
            if got is not None:
                await self.push(got)
            if now >= next_stats:
                next_stats = now + STATS_EVERY_S
                server = await self.call(self._stats)
                await self.send_json(
                    {"type": "stats", "server": server, "bridge": self.counters.summary()}
                )
            next_push += period
            delay = next_push - time.perf_counter()
            if delay < -period:  # far behind (a slow server): do not try to catch up the pushes
                next_push = time.perf_counter()
            await asyncio.sleep(max(0.0, delay))

    async def push(self, got: Got) -> None:
        """Encode and send one frame. The bridge's own time on it runs from the moment its reply
        arrived (in the worker thread) to the moment its bytes are written to the page's socket:
        the hop back to the event loop, the encoding and the send."""
        data = encode_frame(
            got.k, got.t, got.z, force=got.force, bridge_us=self.last_bridge_us, flags=got.flags
        )
        await self.ws.send_bytes(data)
        self.last_bridge_us = (time.perf_counter() - got.received) * 1e6
        self.counters.bridge_us.append(self.last_bridge_us)
        self.counters.frames += 1

    def _film(self, info: SceneInfo, sim_elapsed: float) -> Got:
        assert self.client is not None
        k = int(sim_elapsed / info.dt) % max(info.steps, 1)
        t = info.start_offset + k * info.dt
        frame = self.client.query(t, self.config.scene)
        return Got(k, t, frame.z, float("nan"), 0, time.perf_counter())

    def _steps(self, info: SceneInfo, sim_elapsed: float, budget_s: float) -> Got | None:
        """The steps due by ``sim_elapsed``, the last with a frame, within ``budget_s`` of wall
        clock; the steps left when the budget runs out are dropped (the session falls behind
        wall-clock time, counted in ``dropped_steps``) rather than queued."""
        session = self.session
        assert session is not None
        if self.pointer.reset:
            self.pointer.reset = False
            self.skipped += session.k
            session.reset()
        due = int(sim_elapsed / info.dt) - self.skipped - session.k
        if due <= 0:
            return None
        deadline = time.perf_counter() + budget_s
        probes = self.pointer.probes()
        taken = 1
        while taken < due and time.perf_counter() < deadline:
            session.step(probes=probes, frame=False)
            taken += 1
        frame = session.step(probes=probes, frame=True)
        received = time.perf_counter()
        self.counters.steps += taken
        self.counters.dropped_steps += due - taken
        self.skipped += due - taken
        force = frame.probes[0].force if frame.probes else 0.0
        flags = FLAG_LIVE | (FLAG_CONTACT if frame.probes and frame.probes[0].in_contact else 0)
        assert frame.z is not None
        return Got(frame.k, frame.t, frame.z, force, flags, received)

    def _stats(self) -> dict[str, Any]:
        assert self.client is not None
        stats = self.client.stats()
        latency = stats.get("latency_us", {})
        return {
            "requests": stats.get("requests"),
            "latency_us": {q: latency.get(q) for q in ("p50", "p99", "max")},
            "live_steps": stats.get("live", {}).get("steps"),
            "uptime_s": stats.get("uptime_s"),
        }

    def on_message(self, text: str) -> None:
        """A pointer message from the page (bad ones are ignored: the page is ours)."""
        try:
            message = json.loads(text)
            kind = message.get("type")
            if kind == "press":
                at = tuple(float(v) for v in message["at"])
                depth, radius = float(message["depth"]), float(message["radius"])
                if not all(map(math.isfinite, (*at, depth, radius))) or depth < 0 or radius <= 0:
                    raise ValueError("non-finite or negative probe")
                self.pointer.at, self.pointer.depth, self.pointer.radius = at, depth, radius
            elif kind == "release":
                self.pointer.at = None
            elif kind == "reset":
                self.pointer.reset = True
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            logger.debug("ignored a message from the page: %r (%s)", text[:200], exc)


def _explain(exc: MembraneError, config: BridgeConfig) -> str:
    if isinstance(exc, Timeout):
        return f"server unreachable at {config.connect} ({exc}); retrying"
    text = str(exc)
    if "session" in text.lower():
        return f"session lost ({text}); opening a new one"
    return f"{type(exc).__name__}: {text}; retrying"


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return None


async def _websocket(request: web.Request) -> web.WebSocketResponse:
    # No permessage-deflate: float32 noise hardly compresses, and deflating 40 kB takes ms.
    ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=1 << 16, compress=False)
    await ws.prepare(request)
    player = Player(request.app[CONFIG], ws)
    task = asyncio.create_task(player.run())
    try:
        async for message in ws:
            if message.type == WSMsgType.TEXT:
                player.on_message(message.data)
            elif message.type == WSMsgType.ERROR:
                break
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await task  # a failure was logged by Player.run
    return ws


async def _index(request: web.Request) -> web.FileResponse:
    return web.FileResponse(static_dir() / "index.html")


CONFIG: web.AppKey[BridgeConfig] = web.AppKey("config", BridgeConfig)


def make_app(config: BridgeConfig) -> web.Application:
    """The aiohttp application: the page, its modules, the WebSocket."""
    app = web.Application()
    app[CONFIG] = config
    app.router.add_get("/", _index)
    app.router.add_get("/ws", _websocket)
    app.router.add_static("/static/", static_dir(), show_index=False)
    return app
