"""The bridge: a membrane client on one side, a web page on the other (aiohttp).

``GET /`` serves the page (static/, package data), ``GET /ws`` a WebSocket. Per WebSocket the
bridge holds one ``Client`` (used from the bridge's worker threads, one call at a time: the
client blocks, the event loop must not) and pushes:

- ``{"type": "scene", ...}`` (JSON text) once described: shape, extent, dt, live or film;
- binary frames (``wire.encode_frame``: a 32-byte header and float32 z) at up to ``fps`` per
  second: a film scene plays at ``speed`` x its dt (frame for simulation time ``elapsed *
  speed``, looping); a live scene is stepped at one step per dt of wall-clock time (times
  ``speed``), the steps due since the last push in one batch, only the last with a frame;
- ``{"type": "stats", ...}`` once a second: the server's counters and percentiles, the bridge's
  own time per frame (encode and send), frames pushed, steps taken and steps dropped (behind);
- ``{"type": "error", "message": ...}`` when the server is unreachable or a session expired; the
  bridge retries once a second and says ``{"type": "status", ...}`` when it is back.

The page sends JSON text: a press, ``{"type": "press"}`` with a probe's wire map besides
(``live_schema.Probe``: lattice coordinates, problem units), while the pointer is down,
``{"type": "release"}`` when it is up, and ``{"type": "reset"}``. Each is checked
(``page_input``: size, nesting, the scene's bounds through ``LiveLimits``, the depth within the
slider's range); a bad one is answered with ``{"type": "error", "source": "page", ...}`` and
changes nothing, the session kept.

Who may talk to it (``guard``): the page and its WebSocket are the user's session on the
tissue, and any web page the user visits can send requests to 127.0.0.1. So every request must
name the bridge itself in ``Host`` (a DNS-rebound name does not), an ``Origin`` must be the
bridge's own, the page and the WebSocket need the start-up token (``?token=``, as Jupyter's),
and at most ``max_connections`` WebSockets are held at once, all served by one small thread
pool: the rest get 403 or 503 before any session is opened.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import wait as wait_for
from dataclasses import dataclass, field
from functools import partial
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np
from aiohttp import WSCloseCode, WSMsgType, web

from membrane_client.client import Client
from membrane_client.curve import SocketOptions
from membrane_client.errors import ServerError, Timeout
from membrane_client.frame import SceneInfo
from membrane_client.live_limits import LiveLimits
from membrane_client.live_schema import Grasp, Probe, Tool
from membrane_client.protocol import MAX_REPEAT, ErrorCode
from membrane_client.session import LiveFrame, Session
from membrane_errors import MembraneError
from membrane_view.guard import guard, new_token, security_headers
from membrane_view.page_input import (
    PAGE_TOOLS,
    PageInputError,
    error_message,
    parse_page_message,
)
from membrane_view.wire import FLAG_CONTACT, FLAG_LIVE, encode_frame

__all__ = ["BridgeConfig", "make_app", "static_dir"]

logger = logging.getLogger(__name__)
T = TypeVar("T")

RETRY_S = 1.0
STATS_EVERY_S = 1.0
MAX_CONNECTIONS = 8
WORKERS = 4
# Bytes of one message from the page before aiohttp closes the socket (1009); under it, a
# message over page_input.MAX_MESSAGE_CHARS is answered with an error and the socket kept.
MAX_FRAME_BYTES = 1 << 16


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
    token: str = field(default_factory=new_token)  # needed by the page and the WebSocket
    max_connections: int = MAX_CONNECTIONS  # WebSockets held at once; more get 503
    workers: int = WORKERS  # threads that make the client's (blocking) calls, for all pages

    def __post_init__(self) -> None:
        if len(self.token) < 16:
            raise ValueError("the token must be at least 16 characters")
        if self.max_connections < 1 or self.workers < 1:
            raise ValueError("max_connections and workers must be >= 1")


@dataclass
class Pointer:
    """The page's pointer: while pressed, the tool it presses with (``page_input.PAGE_TOOLS``)."""

    at: tuple[float, ...] | None = None
    depth: float = 0.0
    radius: float = 0.05
    tool: str = "tip"
    reset: bool = False

    def inputs(self) -> StepInputs:
        """The step's inputs: a probe (the soft tip), a rigid tool, or a grasp held at +depth."""
        if self.at is None:
            return StepInputs()
        if self.tool == "grasp":
            return StepInputs(grasps=(Grasp(self.at, self.depth, self.radius),))
        if self.tool in ("sphere", "cylinder"):
            return StepInputs(tools=(Tool(self.tool, self.at, self.depth, self.radius),))
        return StepInputs(probes=(Probe(self.at, self.depth, self.radius),))


class StepInputs(NamedTuple):
    """What one step presses with (at most one of them, from the pointer)."""

    probes: tuple[Probe, ...] = ()
    tools: tuple[Tool, ...] = ()
    grasps: tuple[Grasp, ...] = ()

    def __bool__(self) -> bool:
        return bool(self.probes or self.tools or self.grasps)


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
    extent = _extent(info)
    triangles = info.triangles
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
        "units": display_units(info),
        # a press's depth and radius in the scene's units: the slider's range (a press deeper
        # than depth_max is refused)
        "depth_max": depth_max(info),
        "radius": tip_radius(info),
        "tool_radius": 0.1 * extent,
        "tools": page_tools(info),
        "min_radius": float(info.live.get("min_radius", 0.0)) if live else 0.0,
        # A point list (shape (n,)) is drawn where its points are: a rope along their x, a
        # membrane's points as a scatter or on their triangles. A grid needs no points.
        "points": points.tolist() if len(info.shape) == 1 else None,
        # A physical scene's lattice triangles on the tissue (a disk's grid: its inside only).
        "triangles": None if triangles is None else [int(v) for v in triangles.reshape(-1)],
    }


def display_units(info: SceneInfo) -> dict[str, Any]:
    """How the page labels lengths, displacements and forces: mm and N on a physical scene (SI
    on the wire, lengths shown x 1000), "problem units" on a dimensionless one."""
    if info.units.get("length") == "m":
        return {"length": "mm", "factor": 1e3, "force": "N", "physical": True}
    return {"length": "problem units", "factor": 1.0, "force": "problem units", "physical": False}


def page_tools(info: SceneInfo) -> list[str]:
    """The page's tools the live scene takes, in ``PAGE_TOOLS``'s order (none on a film)."""
    if not info.live:
        return []
    inputs = set(info.live.get("inputs", ["probes"]))
    kinds = set(info.live.get("tool_kinds", ()))
    takes = {"tip": "probes" in inputs, "grasp": "grasps" in inputs}
    return [t for t in PAGE_TOOLS if takes.get(t, "tools" in inputs and t in kinds)]


def tip_radius(info: SceneInfo) -> float:
    """The soft tip's (and the grasp's) footprint: the largest a tissue's tables carry (a point,
    0, on the skin patch), else 5 % of the lattice's extent."""
    radii = info.live.get("radii") if info.live else None
    if radii:
        return float(max(radii))
    return 0.05 * _extent(info)


def _extent(info: SceneInfo) -> float:
    points = np.asarray(info.points, dtype=np.float64)
    return float(np.max(points.max(axis=0) - points.min(axis=0))) if points.size else 1.0


def live_limits(info: SceneInfo) -> LiveLimits | None:
    """A live scene's bounds on a step (None on a film)."""
    if not info.live:
        return None
    dims = int(info.points.shape[1]) if info.points.ndim == 2 else 1
    return LiveLimits.from_live(info.live, dims)


def depth_max(info: SceneInfo) -> float:
    """The page slider's deepest press: 2 % of the lattice's extent on a dimensionless scene,
    10 % on a physical one (5 mm on a 50 mm patch: large deflection on a 3 mm plate), or the
    scene's own ``max_depth`` if that is less. A press deeper than it is refused."""
    share = 0.1 if display_units(info)["physical"] else 0.02
    slider = share * _extent(info)
    limits = live_limits(info)
    return slider if limits is None else min(slider, limits.max_depth)


class Got(NamedTuple):
    """A frame from the server, and when its reply arrived (perf_counter)."""

    k: int
    t: float
    z: np.ndarray
    force: float
    flags: int
    received: float


class StepRefused(MembraneError):
    """The server refused a step's probe (``bad_request``): the page's press is dropped, the
    session kept (reopening it would not make the probe valid)."""


class Player:
    """One page's connection to the server: films played, live scenes stepped.

    Its client calls go to the bridge's shared worker threads one at a time (``call`` waits
    for the previous one, even when cancelled): a Client is not thread-safe.
    """

    def __init__(
        self, config: BridgeConfig, ws: web.WebSocketResponse, executor: ThreadPoolExecutor
    ):
        self.config, self.ws, self.executor = config, ws, executor
        self.pointer = Pointer()
        self.counters = Counters()
        self.client: Client | None = None
        self.session: Session | None = None
        self.info: SceneInfo | None = None
        self.limits: LiveLimits | None = None
        self.depth_max = 0.0
        self.tools: tuple[str, ...] = ()
        self.last_bridge_us = 0.0
        self.skipped = 0  # steps of wall-clock time not taken (dropped, or before a reset)
        self.inflight: Future[Any] | None = None
        self.sending = asyncio.Lock()  # the play loop and the receive loop both send

    async def call(self, fn: Callable[[], T]) -> T:
        previous = self.inflight
        if previous is not None and not previous.done():  # its awaiter was cancelled
            await asyncio.wait([asyncio.wrap_future(previous)])
        future = self.executor.submit(fn)
        self.inflight = future
        return await asyncio.wrap_future(future)

    async def send_json(self, message: dict[str, Any]) -> None:
        text = json.dumps(message, allow_nan=False, default=_jsonable)
        async with self.sending:
            await self.ws.send_str(text)

    async def on_text(self, text: str) -> None:
        """A message from the page: applied to the pointer, or refused with an error message
        (the pointer and the session unchanged, the socket kept open)."""
        try:
            no_press = (
                "press needs a live scene (this one plays a film)"
                if self.info is not None
                else "no scene yet: press once the scene message has come"
            )
            message = parse_page_message(
                text, self.limits, self.depth_max, no_press, tools=self.tools
            )
        except PageInputError as exc:
            await self.send_json(error_message(f"page message refused: {exc}", source="page"))
            return
        if message.probe is not None:
            probe = message.probe
            self.pointer.at, self.pointer.depth, self.pointer.radius = probe
            self.pointer.tool = message.tool
        elif message.kind == "release":
            self.pointer.at = None
        elif message.kind == "reset":
            self.pointer.reset = True

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

    def _described(self, info: SceneInfo) -> None:
        """The scene's bounds for the page's presses; a press from before is dropped (it was
        checked against another description)."""
        self.info = info
        self.limits = live_limits(info)
        self.depth_max = depth_max(info)
        self.tools = tuple(page_tools(info))
        self.pointer.at = None

    def _close_after(self, pending: Future[Any] | None) -> None:
        """In a worker: wait for the call still running, then close (never two at once)."""
        if pending is not None:
            wait_for([pending])
        self._close()

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
                    info = await self.call(self._connect)
                except MembraneError as exc:
                    await self.send_json(error_message(_explain(exc, self.config)))
                    await self.call(self._close)
                    await asyncio.sleep(RETRY_S)
                    continue
                self._described(info)
                await self.send_json(scene_message(info, self.config))
                where = f"connected to {self.config.connect}, scene {_short(info.name)}"
                await self.send_json({"type": "status", "message": where})
                try:
                    await self.play(info)
                except MembraneError as exc:
                    if self.ws.closed:
                        break
                    await self.send_json(error_message(_explain(exc, self.config)))
                    await self.call(self._close)
                    await asyncio.sleep(RETRY_S)
        except ConnectionResetError:  # the page went away while a message was being sent
            pass
        except Exception as exc:  # a bug: logged with its traceback, and shown on the page
            logger.exception("the bridge failed")
            with contextlib.suppress(Exception):
                await self.send_json(error_message(f"the bridge failed: {exc!r}"))
            raise
        finally:
            # Submitted at once, so the session is closed even if this task is cancelled again.
            try:
                closing = self.executor.submit(self._close_after, self.inflight)
            except RuntimeError:  # the workers are stopped: the bridge is exiting
                logger.debug("a session left open at exit (the server expires it)")
            else:
                await asyncio.shield(asyncio.wrap_future(closing))

    async def play(self, info: SceneInfo) -> None:
        period = 1.0 / self.config.fps
        started = time.perf_counter()
        next_push, next_stats = started, started
        self.skipped = 0
        while not self.ws.closed:
            now = time.perf_counter()
            sim_elapsed = (now - started) * self.config.speed
            if info.live:
                try:
                    got = await self.call(partial(self._steps, info, sim_elapsed, 0.8 * period))
                except StepRefused as exc:
                    self.pointer.at = None
                    await self.send_json(error_message(str(exc), source="page"))
                    got = None
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
        """The steps due by ``sim_elapsed`` in requests of up to ``MAX_REPEAT`` steps (one, at
        60 pushes a second of a 1 kHz scene), the last with a frame, within ``budget_s`` of
        wall clock; the steps left when the budget runs out are dropped (the session falls
        behind wall-clock time, counted in ``dropped_steps``) rather than queued."""
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
        inputs = self.pointer.inputs()
        taken = 0
        try:
            while True:
                repeat = min(MAX_REPEAT, due - taken)
                last = taken + repeat == due or time.perf_counter() >= deadline
                frame = session.step(
                    probes=inputs.probes,
                    tools=inputs.tools,
                    grasps=inputs.grasps,
                    frame=last,
                    repeat=repeat,
                )
                taken += repeat
                if last:
                    break
        except ServerError as exc:
            if exc.code != ErrorCode.BAD_REQUEST or not inputs:
                raise
            self.skipped += due - taken  # the refused steps' wall-clock time is not taken
            raise StepRefused(f"the server refused the press: {exc.message}") from None
        received = time.perf_counter()
        self.counters.steps += taken
        self.counters.dropped_steps += due - taken
        self.skipped += due - taken
        force, contact = _felt(frame)
        flags = FLAG_LIVE | (FLAG_CONTACT if contact else 0)
        assert frame.z is not None
        return Got(frame.k, frame.t, frame.z, force, flags, received)

    def _stats(self) -> dict[str, Any]:
        assert self.client is not None
        stats = self.client.stats()
        latency = stats.latency_us or {}
        return {
            "requests": stats.requests,
            "latency_us": {q: latency.get(q) for q in ("p50", "p99", "max")},
            "live_steps": (stats.live or {}).get("steps"),
            "uptime_s": stats.uptime_s,
        }


def _felt(frame: LiveFrame) -> tuple[float, float]:
    """The pressing tool's force (N or problem units) and whether it touches: a probe's or a
    tool's contact force (>= 0), a grasp's holding force (> 0 lifts the tissue)."""
    if frame.probes:
        return frame.probes[0].force, frame.probes[0].in_contact
    if frame.tools:
        return frame.tools[0].force, frame.tools[0].contacts > 0
    if frame.grasps:
        return frame.grasps[0].force, not frame.grasps[0].outside
    return 0.0, False


def _short(text: str, limit: int = 64) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


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


@dataclass
class Pages:
    """The WebSockets held now, and the threads that serve them all."""

    executor: ThreadPoolExecutor
    open: int = 0
    sockets: set[web.WebSocketResponse] = field(default_factory=set)


async def _websocket(request: web.Request) -> web.StreamResponse:
    config, pages = request.app[CONFIG], request.app[PAGES]
    if pages.open >= config.max_connections:
        return web.Response(
            status=503,
            text=f"503: this bridge serves at most {config.max_connections} pages at once "
            "(--max-connections); close one and reload\n",
        )
    pages.open += 1
    try:
        # No permessage-deflate: float32 noise hardly compresses, and deflating 40 kB takes ms.
        ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=MAX_FRAME_BYTES, compress=False)
        await ws.prepare(request)
        pages.sockets.add(ws)
        player = Player(config, ws, pages.executor)
        task = asyncio.create_task(player.run())
        try:
            async for message in ws:
                if message.type == WSMsgType.TEXT:
                    await player.on_text(message.data)
                elif message.type == WSMsgType.BINARY:
                    refused = "page message refused: the page sends JSON text, not binary"
                    await player.send_json(error_message(refused, source="page"))
                elif message.type == WSMsgType.ERROR:
                    break
        except ConnectionResetError:  # the page went away while it was being answered
            pass
        finally:
            pages.sockets.discard(ws)
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task  # a failure was logged by Player.run
        return ws
    finally:
        pages.open -= 1


async def _index(request: web.Request) -> web.FileResponse:
    return web.FileResponse(static_dir() / "index.html")


CONFIG: web.AppKey[BridgeConfig] = web.AppKey("config", BridgeConfig)
PAGES: web.AppKey[Pages] = web.AppKey("pages", Pages)


def make_app(config: BridgeConfig) -> web.Application:
    """The aiohttp application: the page, its modules, the WebSocket, behind the guard."""
    app = web.Application(middlewares=[guard(config.token)])
    app[CONFIG] = config
    app[PAGES] = Pages(ThreadPoolExecutor(config.workers, thread_name_prefix="membrane-view"))
    app.router.add_get("/", _index)
    app.router.add_get("/ws", _websocket)
    app.router.add_static("/static/", static_dir(), show_index=False)
    app.on_response_prepare.append(security_headers)
    app.on_shutdown.append(_close_pages)
    app.on_cleanup.append(_stop_workers)
    return app


async def _close_pages(app: web.Application) -> None:
    """At exit: tell each page the bridge is going away (1001) rather than drop it."""
    sockets = list(app[PAGES].sockets)
    await asyncio.gather(
        *(ws.close(code=WSCloseCode.GOING_AWAY, message=b"bridge stopping") for ws in sockets),
        return_exceptions=True,
    )


async def _stop_workers(app: web.Application) -> None:
    app[PAGES].executor.shutdown(wait=False)  # the sessions' closes still queued run
