"""From request bytes to reply bytes: envelope checks, the ops, and the served scenes.

No sockets here (server.py owns them), so every rule of docs/PROTOCOL.md can be tested by
calling ``Dispatcher.handle`` directly. ``handle`` never raises: every request, however malformed,
gets exactly one reply.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

from membrane_cli.dispatcher import version
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
from membrane_server.live import LiveOps
from membrane_server.reply_encoding import EncodedFields, encode_ok_reply
from membrane_server.served import ServedScene
from membrane_server.sessions import SessionTable
from membrane_server.timeline import OutOfDomain

__all__ = ["Answer", "Dispatcher", "RequestError", "server_version"]

logger = logging.getLogger(__name__)


@functools.cache
def server_version() -> str:
    """'membrane X.Y.Z', what ``membrane --version`` prints (read once: ``hello`` must stay
    cheap)."""
    return version()


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
        workers: Every worker's endpoint when this is one of several (``serve --workers``):
            ``hello`` lists them, so that a client given one finds the others.
    """

    def __init__(
        self,
        scenes: Sequence[ServedScene],
        stats_snapshot: Callable[[], dict[str, Any]] | None = None,
        sessions: SessionTable | None = None,
        peer_limits: Callable[[], Mapping[str, int]] | None = None,
        workers: Sequence[str] = (),
    ) -> None:
        if not scenes:
            raise ValueError("a server needs at least one scene")
        self.scenes = {served.name: served for served in scenes}
        if len(self.scenes) != len(scenes):
            names = [served.name for served in scenes]
            raise ValueError(f"scene names must be distinct, got {names}")
        self._stats_snapshot = stats_snapshot or dict
        self._peer_limits = peer_limits
        self.workers = tuple(workers)
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
        decoded = self._decode(body)
        if isinstance(decoded, Answer):
            return decoded
        return self._answer(decoded, peer)

    def handle_many(self, requests: Sequence[tuple[Sequence[bytes], str]]) -> Iterator[Answer]:
        """Answer requests already queued (each its payload frames and peer), in order, as
        ``handle`` would one by one, each answer given as soon as it is made (the caller sends
        it before the next is made: no more replies are held at once than a run's). Never
        raises.

        A run of ``step`` requests is answered together (``LiveOps.step_run``): the steps of
        loads alone on one engine are stepped as one operation, each still the step it stands
        for. Any other request ends the run first, so that it sees every step before it.
        """
        run: list[Request] = []
        peers: list[str] = []
        for body, peer in requests:
            decoded = self._decode(body)
            if isinstance(decoded, Request) and decoded.op == Op.STEP:
                run.append(decoded)
                peers.append(peer)
                continue
            yield from self._step_run(run, peers)
            run, peers = [], []
            yield decoded if isinstance(decoded, Answer) else self._answer(decoded, peer)
        yield from self._step_run(run, peers)

    def _decode(self, body: Sequence[bytes]) -> Request | Answer:
        """The request in ``body``, or the error answer to it."""
        if len(body) != 1:
            reason = f"expected one payload frame, got {len(body)}"
            return self._error(None, ErrorCode.BAD_MESSAGE, reason)
        try:
            return Request.from_wire(body[0])
        except RequestError as exc:
            envelope = exc.request  # op and session are recorded once the envelope is valid
            op, session = (None, None) if envelope is None else (envelope.op, envelope.session)
            return self._error(exc.request_id, exc.code, str(exc), op, session)

    def _answer(self, request: Request, peer: str) -> Answer:
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
            return self._failed(request, exc)
        return Answer(reply, request.op, None, None, request.session)

    def _step_run(self, run: Sequence[Request], peers: Sequence[str]) -> list[Answer]:
        if len(run) <= 1:
            return [self._answer(request, peer) for request, peer in zip(run, peers, strict=True)]
        try:
            found = self._live.step_run(list(zip(run, peers, strict=True)))
        except Exception as exc:  # a bug costs the run's replies, never the server
            return [self._failed(request, exc) for request in run]
        answers = []
        for request, answer in zip(run, found, strict=True):
            if isinstance(answer, RequestError):
                code, reason = answer.code, str(answer)
                answers.append(self._error(request.id, code, reason, request.op, request.session))
            else:
                answers.append(Answer(answer, request.op, None, None, request.session))
        return answers

    def _failed(self, request: Request, exc: Exception) -> Answer:
        logger.error("internal error answering op %s", request.op, exc_info=exc)
        reason = f"the server failed answering this request: {type(exc).__name__}"
        return self._error(
            request.id, ErrorCode.INTERNAL_ERROR, reason, request.op, request.session
        )

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
            workers=self.workers,
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
_LiveHandler = Callable[[LiveOps, Request, str], bytes | dict[str, Any]]
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
    Op.STEPS: LiveOps.steps,
    Op.STEP_COLUMNS: LiveOps.step_columns,
}
