"""From request bytes to reply bytes: envelope checks, the ops, and the served scenes.

No sockets here (server.py owns them), so every rule of docs/PROTOCOL.md can be tested by
calling ``Dispatcher.handle`` directly. ``handle`` never raises: every request, however malformed,
gets exactly one reply.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from membrane_client.frame import Frame, SceneInfo
from membrane_client.protocol import (
    MAX_LATTICE_POINTS,
    MAX_REQUEST_BYTES,
    PROTOCOL_VERSION,
    ErrorCode,
    Op,
    Request,
    RequestError,
    encode,
    error_reply,
    ok_reply,
    preview,
)
from membrane_client.replies import HelloReply, ServerLimits, StatsReply
from membrane_models.live import LiveEngine, LiveError
from membrane_server.engines import UnknownEngine
from membrane_server.evaluators import Evaluator, build_evaluator
from membrane_server.live import LiveOps, SessionTable, build_scene_engine, live_description
from membrane_server.reply_cache import ReplyCache
from membrane_server.reply_encoding import EncodedFields, encode_fields, encode_ok_reply
from membrane_server.scene import Scene, SceneError, load_scene
from membrane_server.source import ModelSource, resolve_source
from membrane_server.timeline import OutOfDomain, Sample, Timeline

__all__ = ["Answer", "Dispatcher", "RequestError", "ServedScene", "server_version"]

logger = logging.getLogger(__name__)

UNITS = {
    "time": "s (simulation time; model time t = step * dt)",
    "lattice": "problem units (nondimensional, the model's spatial domain)",
    "displacement": "problem units (nondimensional)",
    "world": "simulator units: origin + size * lattice coordinate, + scale * displacement",
}


_DISTRIBUTIONS = ("membrane-tissue", "membrane")


@functools.cache
def server_version() -> str:
    """'membrane X.Y.Z' from the installed distribution (read once: ``hello`` must stay cheap)."""
    for distribution in _DISTRIBUTIONS:
        try:
            return f"membrane {metadata.version(distribution)}"
        except metadata.PackageNotFoundError:
            continue
    return "membrane (not installed)"


class ServedScene:
    """A scene ready to answer: its evaluator built once, its time grid, its describe payload."""

    def __init__(
        self,
        scene: Scene,
        evaluator: Evaluator,
        source: ModelSource,
        live: LiveEngine[Any] | None = None,
    ) -> None:
        self.scene = scene
        self.evaluator = evaluator
        self.source = source
        self.live = live  # a live scene's engine: sessions step it (membrane_server.live)
        self.timeline = Timeline(
            dt=scene.dt,
            last_step=scene.last_step,
            start_offset=scene.start_offset,
            snapping=scene.snapping,
            policy=scene.policy,
        )
        self.shape = scene.lattice.shape
        description = self._describe()
        # Encoded once: a 65,536-point lattice's describe is a megabyte of coordinates.
        encoded = encode_fields(description)
        # The revision names this content: a reload that changes anything a client relies on
        # (lattice, placement, time grid, model) changes it, and clients see it in every reply.
        self.revision = hashlib.sha256(encoded.data).hexdigest()[:12]
        self._description = {**description, "revision": self.revision}
        self.encoded_description = encoded.plus("revision", self.revision)
        self._replies = ReplyCache()

    @classmethod
    def load(cls, scene: Scene | str | Path, threads: int = 1) -> ServedScene:
        """Load a scene (object, built-in name or path), resolve its model once, build its
        evaluator from that."""
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        source = resolve_source(scene)
        started = time.perf_counter()
        try:
            evaluator = build_evaluator(scene, source, threads=threads)
            engine = None if scene.live is None else build_scene_engine(scene, source.problem)
        except (SceneError, LiveError, UnknownEngine) as exc:  # where the file is not known
            raise scene.error(exc) from None
        logger.info(
            "scene %s: %s evaluator, %d points, model %s, built in %.2f s",
            scene.name, evaluator.kind, evaluator.n_points, source.summary()["name"],
            time.perf_counter() - started,
        )  # fmt: skip
        return cls(scene, evaluator, source, engine)

    @property
    def name(self) -> str:
        """The scene's name."""
        return self.scene.name

    def describe(self) -> dict[str, Any]:
        """The ``describe`` reply's fields."""
        return self._description

    def query(self, t: float, dtype: str = "<f4") -> dict[str, Any]:
        """The ``query`` reply's fields for simulation time ``t`` (raises OutOfDomain)."""
        return self._served_frame(self.timeline.resolve(t), t).to_reply_fields(dtype)

    def encoded_query(self, t: float, dtype: str = "<f4") -> EncodedFields:
        """``query``'s fields but ``requested_t``, encoded; those of a time on a step come
        from the reply cache (raises OutOfDomain)."""
        sample = self.timeline.resolve(t)

        def fields() -> EncodedFields:
            frame = self._served_frame(sample, t)
            return encode_fields(frame.to_reply_fields(dtype, requested=False))

        if sample.weight != 0.0:  # between two steps: interpolated, not cached
            return fields()
        return self._replies.get((sample.step, dtype, sample.domain), fields)

    def _served_frame(self, sample: Sample, requested_t: float) -> Frame:
        z = self.frame(sample).reshape(self.shape)
        domain = str(sample.domain)
        return Frame(
            sample.t, sample.step, z, requested_t, domain, self.name, revision=self.revision
        )

    def frame(self, sample: Sample) -> np.ndarray:
        """The (n,) displacement for a resolved sample (interpolated under linear snapping)."""
        frame = self.evaluator.frame(self.timeline.model_time(sample.step))
        if sample.weight == 0.0:
            return frame
        following = self.evaluator.frame(self.timeline.model_time(sample.step + 1))
        mixed: np.ndarray = (1.0 - sample.weight) * frame + sample.weight * following
        return mixed

    def _describe(self) -> dict[str, Any]:
        scene, placement = self.scene, self.scene.placement
        return SceneInfo(
            name=scene.name,
            description=scene.description,
            points=self.evaluator.points,
            shape=tuple(self.shape),
            dt=scene.dt,
            duration=scene.duration,
            start_offset=scene.start_offset,
            steps=scene.steps,
            origin=np.asarray(placement.origin, dtype=np.float64),
            size=placement.size,
            scale=placement.scale,
            axis=placement.axis,
            policy=scene.policy,
            snapping=scene.snapping,
            evaluator=self.evaluator.kind,
            evaluator_info={k: v for k, v in self.evaluator.info().items() if k != "kind"},
            model=self.source.summary(),
            units=UNITS,
            live={} if self.live is None else live_description(self.live),
        ).to_reply_fields()


class Prepared(NamedTuple):
    """An op's reply fields, already encoded, plus a few to encode per request."""

    fields: EncodedFields
    extra: dict[str, Any]
    scene: str | None = None


class Answer(NamedTuple):
    """A reply, plus what the stats need to know about the request (a tuple: one per request,
    built on the hot path)."""

    reply: bytes
    op: str | None = None
    error: str | None = None
    scene: str | None = None
    session: str | None = None


class Dispatcher:
    """Answers requests for a set of served scenes.

    Args:
        scenes: The scenes, with distinct names. With exactly one, requests may omit ``scene``.
        stats_snapshot: Returns the ``stats`` reply's fields (the server passes its Stats').
        sessions: The live sessions' table (kept across reloads by the server).
        peer_limits: Returns the per-peer figures ``hello`` states (``max_in_flight``,
            ``peer_budget_bytes``: the server's, which knows its sockets); none in process.
    """

    def __init__(
        self,
        scenes: Sequence[ServedScene],
        stats_snapshot: Callable[[], dict[str, Any]] | None = None,
        sessions: SessionTable | None = None,
        peer_limits: Callable[[], Mapping[str, int]] | None = None,
    ) -> None:
        if not scenes:
            raise ValueError("a server needs at least one scene")
        self.scenes = {served.name: served for served in scenes}
        if len(self.scenes) != len(scenes):
            names = [served.name for served in scenes]
            raise ValueError(f"scene names must be distinct, got {names}")
        self._stats_snapshot = stats_snapshot or dict
        self._peer_limits = peer_limits
        self._only = scenes[0] if len(scenes) == 1 else None
        # Live sessions outlive a Dispatcher: the server hands every one it makes the same table.
        self.sessions = sessions if sessions is not None else SessionTable()
        # Nothing here refers back to the dispatcher (no bound methods kept, the live ops find
        # scenes through a plain function): a reload's old dispatcher and scenes are freed by
        # reference counting as soon as no session holds them, not at a full collection.
        self._live = LiveOps(self.sessions, functools.partial(find_scene, self.scenes, self._only))

    @property
    def ops(self) -> list[str]:
        """The ops this server answers."""
        return [*_OPS, *_LIVE_OPS]

    @property
    def default_scene(self) -> str | None:
        """The scene requests get when they name none (None when several are hosted)."""
        return next(iter(self.scenes)) if len(self.scenes) == 1 else None

    def handle(self, body: Sequence[bytes], peer: str = "") -> Answer:
        """Answer one request given as its payload frames (exactly one is valid). Never raises.

        ``peer`` names who sent it, for the per-peer session bounds and the sessions' owners:
        ``"key:<z85 public key>"`` with CurveZMQ, ``"conn:<routing id hex>"`` without (the
        server's loop says which); "" in process.

        Nothing from a request is recorded (session, op) unless its envelope is valid, and no
        value a client sent is formatted whole into a reply or a log line (``preview``): the
        checks are ``protocol.Request.from_wire``'s, the schema's owner.
        """
        if len(body) != 1:
            reason = f"expected one payload frame, got {len(body)}"
            return self._error(None, ErrorCode.BAD_MESSAGE, reason)
        try:
            request = Request.from_wire(body[0])
        except RequestError as exc:
            envelope = exc.request  # op and session are recorded once the envelope is valid
            op, session = (None, None) if envelope is None else (envelope.op, envelope.session)
            return self._error(exc.request_id, exc.code, str(exc), op, session)
        try:
            if request.op in _LIVE_OPS:
                fields: dict[str, Any] | Prepared | bytes = _LIVE_OPS[request.op](
                    self._live, request, peer
                )
            else:
                fields = _OPS[request.op](self, request)
            if isinstance(fields, Prepared):
                reply = encode_ok_reply(request.id, fields.fields, **fields.extra)
                return Answer(reply, request.op, None, fields.scene, request.session)
            reply = fields if isinstance(fields, bytes) else encode(ok_reply(request.id, **fields))
        except RequestError as exc:
            return self._error(request.id, exc.code, str(exc), request.op, request.session)
        except Exception as exc:  # a bug must cost one reply, never the server
            logger.exception("internal error answering op %s", request.op)
            reason = f"the server failed answering this request: {type(exc).__name__}"
            return self._error(
                request.id, ErrorCode.INTERNAL_ERROR, reason, request.op, request.session
            )
        return Answer(reply, request.op, None, None, request.session)

    def _scene(self, request: Request) -> ServedScene:
        return find_scene(self.scenes, self._only, request)

    def _error(
        self,
        request_id: int | None,
        code: ErrorCode,
        message: str,
        op: str | None = None,
        session: str | None = None,
    ) -> Answer:
        reply = encode(error_reply(request_id, code, message))
        return Answer(reply, op, str(code), None, session)

    # -- ops ---------------------------------------------------------------------------------

    def _hello(self, request: Request) -> dict[str, Any]:
        limits = ServerLimits(
            max_request_bytes=MAX_REQUEST_BYTES,
            max_lattice_points=MAX_LATTICE_POINTS,
            max_sessions=self.sessions.max_sessions,
            max_sessions_per_peer=self.sessions.max_per_peer,
            session_idle_s=self.sessions.idle_s,
            **(self._peer_limits() if self._peer_limits is not None else {}),
        )
        return HelloReply(
            protocol=PROTOCOL_VERSION,
            server=server_version(),
            ops=tuple(self.ops),
            scenes=tuple(self.scenes),
            default_scene=self.default_scene,
            session=request.session,
            limits=limits,
        ).to_reply_fields()

    def _describe(self, request: Request) -> Prepared:
        return Prepared(self._scene(request).encoded_description, {})

    def _query(self, request: Request) -> Prepared:
        served = self._scene(request)
        t = request.t
        assert t is not None  # Request.from_wire requires it of a query
        try:
            fields = served.encoded_query(t, request.dtype)
        except OutOfDomain as exc:
            raise RequestError(ErrorCode.OUT_OF_DOMAIN, str(exc)) from None
        return Prepared(fields, {"requested_t": t}, served.name)

    def _stats(self, request: Request) -> dict[str, Any]:
        snapshot = self._stats_snapshot()
        return StatsReply.from_snapshot(snapshot, self.sessions.snapshot()).to_reply_fields()

    def _ping(self, request: Request) -> dict[str, Any]:
        return {"pong": True, "time": time.time()}


def find_scene(
    scenes: dict[str, ServedScene], only: ServedScene | None, request: Request
) -> ServedScene:
    """The served scene a request names (the one hosted when it names none)."""
    name = request.scene
    if name is None:
        if only is not None:  # the common case first: one scene, none named
            return only
        hosted = ", ".join(scenes)
        raise RequestError(
            ErrorCode.UNKNOWN_SCENE,
            f"this server hosts several scenes ({hosted}): name one in 'scene'",
        )
    served = scenes.get(name)
    if served is None:
        hosted = ", ".join(scenes)
        raise RequestError(
            ErrorCode.UNKNOWN_SCENE, f"no scene {preview(name)} here; scenes: {hosted}"
        )
    return served


_Handler = Callable[[Dispatcher, Request], "dict[str, Any] | Prepared | bytes"]
_LiveHandler = Callable[[LiveOps, Request, str], bytes]
# Plain functions, not bound methods: a table of a dispatcher's own bound methods would be a
# reference cycle that keeps a reloaded dispatcher (and its scenes) until a full collection.
_OPS: dict[str, _Handler] = {
    Op.HELLO: Dispatcher._hello,
    Op.DESCRIBE: Dispatcher._describe,
    Op.QUERY: Dispatcher._query,
    Op.STATS: Dispatcher._stats,
    Op.PING: Dispatcher._ping,
}
_LIVE_OPS: dict[str, _LiveHandler] = {
    Op.OPEN: LiveOps.open,
    Op.STEP: LiveOps.step,
    Op.READ: LiveOps.read,
    Op.RESET: LiveOps.reset,
    Op.CLOSE: LiveOps.close,
}
