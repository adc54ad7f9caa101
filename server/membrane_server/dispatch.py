"""From request bytes to reply bytes: envelope checks, the ops, and the served scenes.

No sockets here (server.py owns them), so every rule of docs/PROTOCOL.md can be tested by
calling ``Dispatcher.handle`` directly. ``handle`` never raises: every request, however malformed,
gets exactly one reply.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from membrane_client.errors import ProtocolError
from membrane_client.protocol import (
    ARRAY_DTYPES,
    MAX_LATTICE_POINTS,
    MAX_REQUEST_BYTES,
    MAX_SESSION_CHARS,
    PROTOCOL_VERSION,
    EncodedFields,
    ErrorCode,
    Op,
    decode,
    encode,
    encode_fields,
    encode_ok_reply,
    error_reply,
    ok_reply,
    pack_array,
    preview,
)
from membrane_server.evaluators import Evaluator, build_evaluator
from membrane_server.reply_cache import ReplyCache
from membrane_server.scene import Scene, SceneError, load_scene
from membrane_server.source import ModelSource, resolve_source
from membrane_server.timeline import OutOfDomain, Sample, Timeline

__all__ = ["Answer", "Dispatcher", "RequestError", "ServedScene", "server_version"]

logger = logging.getLogger(__name__)

_MAX_REQUEST_ID = 2**63

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


class RequestError(Exception):
    """A request the server refuses: becomes an error reply with this code."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


class ServedScene:
    """A scene ready to answer: its evaluator built once, its time grid, its describe payload."""

    def __init__(self, scene: Scene, evaluator: Evaluator, source: ModelSource) -> None:
        self.scene = scene
        self.evaluator = evaluator
        self.source = source
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
        """Load a scene (object, built-in name or path) and build its evaluator."""
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        source = resolve_source(scene)
        started = time.perf_counter()
        try:
            evaluator = build_evaluator(scene, source, threads=threads)
        except SceneError as exc:  # raised where the scene's file is not known: name it
            raise scene.error(exc) from None
        logger.info(
            "scene %s: %s evaluator, %d points, model %s, built in %.2f s",
            scene.name, evaluator.kind, evaluator.n_points, source.summary()["name"],
            time.perf_counter() - started,
        )  # fmt: skip
        return cls(scene, evaluator, source)

    @property
    def name(self) -> str:
        """The scene's name."""
        return self.scene.name

    def describe(self) -> dict[str, Any]:
        """The ``describe`` reply's fields."""
        return self._description

    def query(self, t: float, dtype: str = "<f4") -> dict[str, Any]:
        """The ``query`` reply's fields for simulation time ``t`` (raises OutOfDomain)."""
        return {**self._sample_fields(self.timeline.resolve(t), dtype), "requested_t": t}

    def encoded_query(self, t: float, dtype: str = "<f4") -> EncodedFields:
        """``query``'s fields but ``requested_t``, encoded; those of a time on a step come
        from the reply cache (raises OutOfDomain)."""
        sample = self.timeline.resolve(t)
        if sample.weight != 0.0:  # between two steps: interpolated, not cached
            return encode_fields(self._sample_fields(sample, dtype))
        key = (sample.step, dtype, sample.domain)
        return self._replies.get(key, lambda: encode_fields(self._sample_fields(sample, dtype)))

    def _sample_fields(self, sample: Sample, dtype: str) -> dict[str, Any]:
        return {
            "scene": self.name,
            "revision": self.revision,
            "t": sample.t,
            "step": sample.step,
            "domain": str(sample.domain),
            "z": pack_array(self.frame(sample).reshape(self.shape), dtype),
        }

    def frame(self, sample: Sample) -> np.ndarray:
        """The (n,) displacement for a resolved sample (interpolated under linear snapping)."""
        frame = self.evaluator.frame(self.timeline.model_time(sample.step))
        if sample.weight == 0.0:
            return frame
        following = self.evaluator.frame(self.timeline.model_time(sample.step + 1))
        mixed: np.ndarray = (1.0 - sample.weight) * frame + sample.weight * following
        return mixed

    def _describe(self) -> dict[str, Any]:
        scene = self.scene
        return {
            "scene": scene.name,
            "description": scene.description,
            "points": pack_array(self.evaluator.points, "<f8"),
            "shape": list(self.shape),
            "dt": scene.dt,
            "duration": scene.duration,
            "start_offset": scene.start_offset,
            "steps": scene.steps,
            "placement": {
                "origin": list(scene.placement.origin),
                "size": scene.placement.size,
                "scale": scene.placement.scale,
                "axis": scene.placement.axis,
            },
            "policy": scene.policy,
            "snapping": scene.snapping,
            "evaluator": self.evaluator.info(),
            "model": self.source.summary(),
            "units": UNITS,
        }


class Prepared(NamedTuple):
    """An op's reply fields, already encoded, plus a few to encode per request."""

    fields: EncodedFields
    extra: dict[str, Any]
    scene: str | None = None


@dataclass(frozen=True)
class Answer:
    """A reply, plus what the stats need to know about the request."""

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
    """

    def __init__(
        self,
        scenes: Sequence[ServedScene],
        stats_snapshot: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        if not scenes:
            raise ValueError("a server needs at least one scene")
        self.scenes = {served.name: served for served in scenes}
        if len(self.scenes) != len(scenes):
            names = [served.name for served in scenes]
            raise ValueError(f"scene names must be distinct, got {names}")
        self._stats_snapshot = stats_snapshot or dict
        self._only = scenes[0] if len(scenes) == 1 else None
        self._ops: dict[str, Callable[[dict[str, Any]], dict[str, Any] | Prepared]] = {
            Op.HELLO: self._hello,
            Op.DESCRIBE: self._describe,
            Op.QUERY: self._query,
            Op.STATS: self._stats,
            Op.PING: self._ping,
        }

    @property
    def default_scene(self) -> str | None:
        """The scene requests get when they name none (None when several are hosted)."""
        return next(iter(self.scenes)) if len(self.scenes) == 1 else None

    def handle(self, body: Sequence[bytes]) -> Answer:
        """Answer one request given as its payload frames (exactly one is valid). Never raises.

        Nothing from a request is recorded (session, op) unless its envelope is valid, and no
        value a client sent is formatted whole into a reply or a log line (``preview``).
        """
        if len(body) != 1:
            reason = f"expected one payload frame, got {len(body)}"
            return self._error(None, ErrorCode.BAD_MESSAGE, reason)
        try:
            message = decode(body[0], MAX_REQUEST_BYTES)
        except ProtocolError as exc:
            return self._error(None, ErrorCode.BAD_MESSAGE, str(exc))
        request_id = _request_id(message)
        op = message.get("op")
        op_name = op if isinstance(op, str) and op in self._ops else None
        session: str | None = None
        try:
            session = self._check_envelope(message, request_id)
            fields = self._ops[message["op"]](message)
            if isinstance(fields, Prepared):
                reply = encode_ok_reply(request_id, fields.fields, **fields.extra)
                return Answer(reply, op_name, None, fields.scene, session)
            reply = encode(ok_reply(request_id, **fields))
        except RequestError as exc:
            return self._error(request_id, exc.code, str(exc), op_name, session)
        except Exception as exc:  # a bug must cost one reply, never the server
            logger.exception("internal error answering op %s", op_name or "(invalid)")
            message_text = f"the server failed answering this request: {type(exc).__name__}"
            return self._error(request_id, ErrorCode.INTERNAL_ERROR, message_text, op_name, session)
        return Answer(reply, op_name, None, None, session)

    # -- envelope ----------------------------------------------------------------------------

    def _check_envelope(self, message: dict[str, Any], request_id: int | None) -> str | None:
        """Raise RequestError unless the envelope is valid; return its session (or None)."""
        if request_id is None:
            raise RequestError(
                ErrorCode.BAD_REQUEST,
                f"'id' must be an int in [0, 2^63), got {preview(message.get('id'))}",
            )
        version = message.get("v")
        if type(version) is not int or version != PROTOCOL_VERSION:  # 1.0 and True are not 1
            raise RequestError(
                ErrorCode.BAD_VERSION,
                f"protocol version {preview(version)} unsupported; this server speaks "
                f"version {PROTOCOL_VERSION} (an int)",
            )
        op = message.get("op")
        if not isinstance(op, str):
            raise RequestError(ErrorCode.BAD_REQUEST, f"'op' must be a string, got {preview(op)}")
        if op not in self._ops:
            known = ", ".join(self._ops)
            raise RequestError(ErrorCode.UNKNOWN_OP, f"unknown op {preview(op)}; ops: {known}")
        session = message.get("session")
        if session is not None and (
            not isinstance(session, str) or len(session) > MAX_SESSION_CHARS
        ):
            raise RequestError(
                ErrorCode.BAD_REQUEST,
                f"'session' must be a string of at most {MAX_SESSION_CHARS} characters",
            )
        return session

    def _scene(self, message: dict[str, Any]) -> ServedScene:
        name = message.get("scene")
        if name is None:
            if self._only is not None:  # the common case first: one scene, none named
                return self._only
            if self.default_scene is None:
                hosted = ", ".join(self.scenes)
                raise RequestError(
                    ErrorCode.UNKNOWN_SCENE,
                    f"this server hosts several scenes ({hosted}): name one in 'scene'",
                )
            name = self.default_scene
        if not isinstance(name, str):
            raise RequestError(
                ErrorCode.BAD_REQUEST, f"'scene' must be a string, got {preview(name)}"
            )
        served = self.scenes.get(name)
        if served is None:
            hosted = ", ".join(self.scenes)
            raise RequestError(
                ErrorCode.UNKNOWN_SCENE, f"no scene {preview(name)} here; scenes: {hosted}"
            )
        return served

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

    def _hello(self, message: dict[str, Any]) -> dict[str, Any]:
        return {
            "protocol": PROTOCOL_VERSION,
            "server": server_version(),
            "ops": list(self._ops),
            "scenes": list(self.scenes),
            "default_scene": self.default_scene,
            "session": message.get("session"),
            "limits": {
                "max_request_bytes": MAX_REQUEST_BYTES,
                "max_lattice_points": MAX_LATTICE_POINTS,
            },
        }

    def _describe(self, message: dict[str, Any]) -> Prepared:
        return Prepared(self._scene(message).encoded_description, {})

    def _query(self, message: dict[str, Any]) -> Prepared:
        served = self._scene(message)
        t = _time(message)
        dtype = message.get("dtype", "<f4")
        if dtype not in ARRAY_DTYPES:
            allowed = list(ARRAY_DTYPES)
            reason = f"'dtype' must be one of {allowed}, got {preview(dtype)}"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        try:
            fields = served.encoded_query(t, dtype)
        except OutOfDomain as exc:
            raise RequestError(ErrorCode.OUT_OF_DOMAIN, str(exc)) from None
        return Prepared(fields, {"requested_t": t}, served.name)

    def _stats(self, message: dict[str, Any]) -> dict[str, Any]:
        return self._stats_snapshot()

    def _ping(self, message: dict[str, Any]) -> dict[str, Any]:
        return {"pong": True, "time": time.time()}


def _request_id(message: dict[str, Any]) -> int | None:
    value = message.get("id")
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < _MAX_REQUEST_ID:
        return value
    return None


def _time(message: dict[str, Any]) -> float:
    if "t" not in message:
        raise RequestError(ErrorCode.BAD_REQUEST, "query needs 't' (seconds, a float)")
    value = message["t"]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RequestError(ErrorCode.BAD_REQUEST, f"'t' must be a number, got {preview(value)}")
    t = float(value)
    if not math.isfinite(t):
        raise RequestError(ErrorCode.INVALID_TIME, f"'t' must be finite, got {t}")
    return t
