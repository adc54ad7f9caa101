"""The live ops on the server: open, step, read, reset and close, each answering its whole
reply's bytes (so that a re-sent open or step gets exactly the same bytes again); what
``describe`` says of a live scene; the one mapping of engine errors to wire errors.

A step names the index ``k`` it takes: the session's own count applies it. A re-send (a Lazy
Pirate retry after a lost reply) is recognised by the ``Session`` object's own random
``token``, the op and k (and the scene, for ``open``), never by the request id alone: two
clients number their requests alike. Anything else is refused with the session's k. The
sessions themselves, their owners and their bounds are ``sessions``'.

Every wire form is the client's live schema's (``membrane_client.live_schema``): a step's load,
probe, grasp and tool maps are read through it into the engine's own ``Load``, ``Probe``,
``Grasp`` and ``Tool`` (the schema checks their form, the engine their values), and every reply
is one of its reply forms.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from membrane_client import live_schema as schema
from membrane_client.live_schema import (
    MAX_GRASPS,
    MAX_LOADS,
    MAX_PROBES,
    MAX_TOOLS,
    STEP_UNITS,
    CloseReply,
    Initial,
    LiveInputError,
    LiveStepReply,
    OpenReply,
    ResetReply,
)
from membrane_client.protocol import (
    ErrorCode,
    Request,
    RequestError,
    encode,
    error_reply,
    ok_reply,
    preview,
)
from membrane_models.live import (
    BatchedEngine,
    BoundedEngine,
    Grasp,
    GraspReading,
    LiveEngine,
    LiveError,
    Load,
    LookaheadEngine,
    Probe,
    ProbeReading,
    Start,
    StepResult,
    Tool,
    ToolReading,
)
from membrane_models.live.inputs import MAX_DEPTH
from membrane_server.engines import build_engine
from membrane_server.sessions import LiveSession, Sent, SessionTable
from membrane_server.step_columns import step_columns

if TYPE_CHECKING:
    from membrane_server.scene import Scene
    from membrane_server.served import ServedScene

__all__ = [
    "LiveOps",
    "build_scene_engine",
    "engine_inputs",
    "live_description",
    "wire_error",
]

# Python objects around a session (its record, the table's entry, stored replies' headers).
_SESSION_OVERHEAD = 4096
# A live reply beside its frame: the envelope and up to MAX_PROBES, MAX_GRASPS and MAX_TOOLS
# readings.
_REPLY_OVERHEAD = 512 + MAX_PROBES * 160 + MAX_GRASPS * 96 + MAX_TOOLS * 160


def build_scene_engine(scene: Scene, problem: object) -> LiveEngine[Any]:
    """The live engine of a scene with a ``[live]`` table, by its kind, on its lattice and dt
    (a physical scene's kind is ``fem`` unless its table names another)."""
    assert scene.live is not None
    settings = scene.live
    kind = settings.engine
    if scene.tissue is not None and "engine" not in settings.model_fields_set:
        kind = "fem"
    return build_engine(kind, problem, scene.lattice.shape, scene.dt, settings.options)


def live_description(
    engine: LiveEngine[Any], units: dict[str, str] | None = None
) -> dict[str, Any]:
    """``describe``'s ``live`` field: the engine's settings and bounds (its own ``describe``),
    the per-step limits, the memory a session holds at most, and the units of a step
    (``units``: a physical scene's SI ones; default the problem units')."""
    return {
        **engine.describe(),
        "max_loads": MAX_LOADS,
        "max_probes": MAX_PROBES,
        "max_grasps": MAX_GRASPS,
        "max_tools": MAX_TOOLS,
        "session_bytes": session_bytes(engine),
        "units": STEP_UNITS if units is None else units,
    }


def session_bytes(engine: LiveEngine[Any]) -> int:
    """The most one session holds: its start and current states (each at most the engine's
    ``state_bytes``), its stored open and step replies."""
    frame = 8 * math.prod(engine.lattice_shape)  # a float64 frame (dtype "<f8") at most
    return 2 * engine.state_bytes + 2 * _REPLY_OVERHEAD + frame + _SESSION_OVERHEAD


def _grasp_reading(engine_reading: GraspReading) -> schema.GraspReading:
    r = engine_reading
    return schema.GraspReading(r.force, r.displacement, r.outside)


def _tool_reading(engine_reading: ToolReading) -> schema.ToolReading:
    """An engine's tool reading in the schema's form (plain floats and ints, as msgpack packs)."""
    r = engine_reading
    centre = tuple([float(c) for c in r.centre])
    return schema.ToolReading(r.force, centre, int(r.contacts), int(r.points), r.gap, r.penetration)


def _reading(engine_reading: ProbeReading) -> schema.ProbeReading:
    """An engine's probe reading in the schema's form (its wire map is ``to_wire()``)."""
    r = engine_reading
    return schema.ProbeReading(
        r.force,
        r.displacement,
        r.gap,
        r.in_contact,
        r.outside,
        float(r.compliance),
        float(r.static_compliance),
    )


def engine_inputs(
    request: Request, dims: int
) -> tuple[tuple[Load, ...], tuple[Probe, ...], tuple[Grasp, ...], tuple[Tool, ...]]:
    """A step's wire loads, probes, grasps and tools, read through the client's live schema
    (their maps' form), as the engine's own types (whose values the engine checks)."""
    try:
        loads = schema.loads_from_wire(request.loads or (), dims)
        probes = schema.probes_from_wire(request.probes or (), dims)
        grasps = schema.grasps_from_wire(request.grasps or (), dims)
        tools = schema.tools_from_wire(request.tools or (), dims)
    except LiveInputError as exc:
        raise wire_error(exc) from None
    return (
        tuple([Load(*load) for load in loads]),
        tuple([Probe(*probe) for probe in probes]),
        tuple([Grasp(*grasp) for grasp in grasps]),
        tuple([Tool(*tool) for tool in tools]),
    )


class LiveOps:
    """The live ops (open, step, read, reset, close), each returning its whole reply's bytes
    (so that a re-sent open or step can get exactly the same bytes again).

    Args:
        table: The open sessions.
        scene_of: The served scene a request names (the dispatcher's rule, raising its
            refusals); a plain function, so that nothing here refers back to a dispatcher.
    """

    def __init__(self, table: SessionTable, scene_of: Callable[[Request], ServedScene]) -> None:
        self.table, self._scene_of = table, scene_of

    def open(self, request: Request, peer: str = "") -> bytes:
        session_id = _session_id(request)
        served = self._scene_of(request)
        if served.live is None:
            raise RequestError(ErrorCode.NOT_LIVE, f"scene {served.name} is a film, not live")
        existing = self.table.get(session_id, peer)
        if existing is not None:
            same_scene = existing.served.name == served.name
            if same_scene and existing.opened.resent_by(request):  # a re-sent open
                return existing.opened.reply_to(request)
            raise RequestError(ErrorCode.SESSION_EXISTS, "this session id is open: close it first")
        if self.table.taken(session_id):  # another key's: say no more than that it is taken
            raise RequestError(ErrorCode.SESSION_EXISTS, "this session id is taken: pick another")
        start = _start(served.live, request.initial)
        fields = OpenReply(
            session=session_id,
            revision=served.revision,
            displacement_residual=start.displacement_residual,
            velocity_residual=start.velocity_residual,
        ).to_reply_fields()
        reply = encode(ok_reply(request.id, **fields))
        opened = Sent(request.token, request.id, reply)
        self.table.add(session_id, LiveSession(served, start, start.state, opened, peer))
        return reply

    def step(self, request: Request, peer: str = "") -> bytes:
        taken = self._take(request, peer)
        if isinstance(taken, bytes):
            return taken  # a re-send, answered from the store
        return self._step_one(taken)

    def steps(self, request: Request, peer: str = "") -> dict[str, Any]:
        """Several sessions' steps in one request (``steps``, a client of many environments):
        each item is the ``step`` it stands for (its own session, k and token: taken exactly
        once, a re-send answered from its store), answered in order with that step's reply
        bytes, an error reply where the item was refused; a refused item stops no other.
        Items of loads alone are stepped together (``step_run``)."""
        assert request.steps is not None
        items: list[tuple[Request, str] | RequestError] = []
        for item in request.steps:
            try:
                items.append((Request.step_item(item, request.id, request.scene), peer))
            except RequestError as exc:
                items.append(exc)
        answers = self.step_run([item for item in items if not isinstance(item, RequestError)])
        found = iter(answers)
        replies: list[bytes] = []
        for index, item in enumerate(items):
            answer = item if isinstance(item, RequestError) else next(found)
            if isinstance(answer, RequestError):
                reason = f"steps item {index}: {answer}"
                answer = encode(error_reply(request.id, answer.code, reason))
            replies.append(answer)
        return {"steps": replies}

    def step_columns(self, request: Request, peer: str = "") -> dict[str, Any]:
        """Many sessions' steps of loads alone, as columns (``step_columns``)."""
        return step_columns(self.table, self._scene_of(request), request, peer)

    def step_run(self, requests: Sequence[tuple[Request, str]]) -> list[bytes | RequestError]:
        """``step`` requests (each with its peer) answered in order, as if one by one: the steps
        of loads alone on an engine that batches (``BatchedEngine``) are gathered and stepped as
        one operation per engine, until a session comes a second time (its next step needs the
        first's end) or the run ends. Each answer is the reply's bytes or the refusal."""
        answers: list[bytes | RequestError | None] = [None] * len(requests)
        batches: dict[int, list[tuple[int, _Taken]]] = {}
        gathered: set[str] = set()
        for index, (request, peer) in enumerate(requests):
            if request.session in gathered:
                self._flush(batches, answers)
                gathered.clear()
            try:
                taken = self._take(request, peer)
                if isinstance(taken, bytes) or not taken.batchable:
                    answers[index] = taken if isinstance(taken, bytes) else self._step_one(taken)
                    continue
            except RequestError as exc:
                answers[index] = exc
                continue
            batches.setdefault(id(taken.engine), []).append((index, taken))
            gathered.add(taken.session_id)
        self._flush(batches, answers)
        done = [a for a in answers if a is not None]
        assert len(done) == len(requests), "a step neither answered nor refused"
        return done

    def _take(self, request: Request, peer: str) -> bytes | _Taken:
        """A step request checked against its session (k, a re-send, what the engine takes),
        its inputs read: ready to step, or the stored reply of a re-send."""
        session = self._session(request, peer)
        k = request.k
        if k != session.k:  # a re-send, never applied twice, or the mismatch refusal
            assert k is not None  # the protocol requires it of a step
            last = self.table.resent_step(session, k, request.token, request.id)
            return last.reply_to(request)
        engine = session.engine
        _require_inputs(
            engine,
            loads=request.loads,
            probes=request.probes,
            grasps=request.grasps,
            tools=request.tools,
        )
        loads, probes, grasps, tools = engine_inputs(request, engine.spatial_dims)
        if request.strict:
            _require_inside(engine, loads, probes, grasps, tools)
        if request.lookahead and (grasps or tools):
            raise RequestError(
                ErrorCode.BAD_REQUEST, "'lookahead' is for steps of loads and probes only"
            )
        return _Taken(request, session, engine, loads, probes, _held(grasps, tools))

    def _step_one(self, taken: _Taken) -> bytes:
        request, session, engine = taken.request, taken.session, taken.engine
        try:
            result = _steps(engine, session.state, request, taken.loads, taken.probes, taken.held)
        except LiveError as exc:
            raise wire_error(exc) from None
        ahead = None
        if request.lookahead:
            ahead = _lookahead(engine, result.state, taken.loads, taken.probes)
        return self._took(taken, result, request.repeat, ahead)

    def _flush(
        self,
        batches: dict[int, list[tuple[int, _Taken]]],
        answers: list[bytes | RequestError | None],
    ) -> None:
        """Step each engine's gathered steps as one operation and answer them."""
        for batch in batches.values():
            engine = cast(BatchedEngine, batch[0][1].engine)
            results = engine.step_loads(
                [taken.session.state for _, taken in batch],
                [taken.loads for _, taken in batch],
                [taken.request.frame for _, taken in batch],
            )
            for (index, taken), result in zip(batch, results, strict=True):
                if isinstance(result, LiveError):
                    answers[index] = wire_error(result)
                else:
                    answers[index] = self._took(taken, result, 1, None)
        batches.clear()

    def _took(
        self, taken: _Taken, result: StepResult[Any], repeat: int, ahead: list[float] | None
    ) -> bytes:
        """The session takes the step's result; its reply, kept for a re-send."""
        request, session = taken.request, taken.session
        session.apply(result, repeat)
        self.table.counts["steps"] += repeat
        fields = self._state_reply(request, session, result.frame, ahead=ahead).to_reply_fields()
        reply = encode(ok_reply(request.id, **fields))
        session.last_step = Sent(request.token, request.id, reply)
        return reply

    def read(self, request: Request, peer: str = "") -> bytes:
        session = self._session(request, peer)
        frame = session.engine.frame(session.state)
        last = session.last_step  # whose step this state follows
        token = None if last is None else last.token
        fields = self._state_reply(request, session, frame, token).to_reply_fields()
        return encode(ok_reply(request.id, **fields))

    def reset(self, request: Request, peer: str = "") -> bytes:
        session = self._session(request, peer)
        session.reset()
        fields = ResetReply(_session_id(request)).to_reply_fields()
        return encode(ok_reply(request.id, **fields))

    def close(self, request: Request, peer: str = "") -> bytes:
        session_id = _session_id(request)
        closed = self.table.close(session_id, peer)
        return encode(ok_reply(request.id, **CloseReply(session_id, closed).to_reply_fields()))

    def _session(self, request: Request, peer: str) -> LiveSession:
        session = self.table.require(_session_id(request), peer)
        if request.scene is not None and request.scene != session.served.name:
            reason = f"this session is on scene {session.served.name}, not {preview(request.scene)}"
            raise RequestError(ErrorCode.BAD_REQUEST, reason)
        return session

    @staticmethod
    def _state_reply(
        request: Request,
        session: LiveSession,
        frame: np.ndarray | None,
        token: str | None = None,
        ahead: list[float] | None = None,
    ) -> LiveStepReply:
        probes = [_reading(r) for r in session.readings]
        if ahead is not None:
            probes = [r._replace(next_free=z) for r, z in zip(probes, ahead, strict=True)]
        return LiveStepReply(
            session=_session_id(request),
            k=session.k,
            t=session.t,
            revision=session.served.revision,
            probes=tuple(probes),
            grasps=tuple([_grasp_reading(r) for r in session.grasp_readings]),
            tools=tuple([_tool_reading(r) for r in session.tool_readings]),
            z=None if frame is None else np.reshape(frame, session.served.shape),
            token=token,
            dtype=request.dtype,
        )


def _steps(
    engine: LiveEngine[Any],
    state: Any,
    request: Request,
    loads: tuple[Load, ...],
    probes: tuple[Probe, ...],
    held: dict[str, Any],
) -> StepResult[Any]:
    """``request.repeat`` steps under the same inputs, the frame on the last only. The session
    takes the result only once all are taken: a refusal on any leaves it as it was."""
    for remaining in range(request.repeat - 1, -1, -1):
        frame = request.frame and remaining == 0
        result = engine.step(state, loads, probes, frame=frame, **held)
        state = result.state
    return result


def _lookahead(
    engine: LiveEngine[Any],
    state: Any,
    loads: tuple[Load, ...],
    probes: tuple[Probe, ...],
) -> list[float]:
    """Each probe's free displacement at the end of the step from ``state`` (the next step)
    under the same loads: the engine's own ``lookahead``, or else that step taken with the
    probes lifted clear (``MAX_DEPTH`` above the rest surface), whose displacement under each
    tip is then the free one (NaN outside)."""
    if not probes:
        return []
    try:
        if _looks_ahead(engine):
            return [float(z) for z in cast(LookaheadEngine, engine).lookahead(state, loads, probes)]
        clear = [Probe(p.at, -MAX_DEPTH, p.radius) for p in probes]
        after = engine.step(state, loads, clear, frame=False)
    except LiveError as exc:
        raise wire_error(exc) from None
    return [float(r.displacement) for r in after.probes]


_LOOKS_AHEAD: dict[type, bool] = {}


def _looks_ahead(engine: object) -> bool:
    """``isinstance(engine, LookaheadEngine)``, answered once per engine class: a runtime
    protocol check inspects the class's attributes each time (10 us, on every step)."""
    kind = type(engine)
    answer = _LOOKS_AHEAD.get(kind)
    if answer is None:
        answer = _LOOKS_AHEAD[kind] = isinstance(engine, LookaheadEngine)
    return answer


def _session_id(request: Request) -> str:
    assert request.session is not None  # Request.from_wire requires it of the live ops
    return request.session


def wire_error(exc: LiveError | LiveInputError, what: str = "") -> RequestError:
    """The one place a refusal of live input becomes a wire error, the engine's (its values)
    or the live schema's (a wire item's form): ``bad_request`` with its message (both quote
    client values bounded; ``error_reply`` caps the length)."""
    return RequestError(ErrorCode.BAD_REQUEST, f"{what}{exc}")


class _Taken(NamedTuple):
    """A step request checked and read, ready to step."""

    request: Request
    session: LiveSession
    engine: LiveEngine[Any]
    loads: tuple[Load, ...]
    probes: tuple[Probe, ...]
    held: dict[str, Any]  # grasps and tools (``_held``)

    @property
    def session_id(self) -> str:
        return _session_id(self.request)

    @property
    def batchable(self) -> bool:
        """A step of loads alone, once, on an engine that batches (``BatchedEngine``)."""
        request = self.request
        plain = not (self.probes or self.held or request.lookahead) and request.repeat == 1
        return plain and _batches(self.engine)


_BATCHES: dict[type, bool] = {}


def _batches(engine: object) -> bool:
    """``isinstance(engine, BatchedEngine)``, answered once per engine class (as
    ``_looks_ahead``)."""
    kind = type(engine)
    answer = _BATCHES.get(kind)
    if answer is None:
        answer = _BATCHES[kind] = isinstance(engine, BatchedEngine)
    return answer


def _held(grasps: tuple[Grasp, ...], tools: tuple[Tool, ...]) -> dict[str, Any]:
    """A step's keyword inputs beyond loads and probes: only those it has, so that an engine
    that takes no grasps or no tools (refused before, by ``_require_inputs``) is never given
    the keyword."""
    held: dict[str, Any] = {}
    if grasps:
        held["grasps"] = grasps
    if tools:
        held["tools"] = tools
    return held


def _require_inside(
    engine: LiveEngine[Any],
    loads: tuple[Load, ...],
    probes: tuple[Probe, ...],
    grasps: tuple[Grasp, ...] = (),
    tools: tuple[Tool, ...] = (),
) -> None:
    """A ``strict`` step: every load, probe, grasp and tool centred in the domain, or a refusal
    naming it."""
    if not isinstance(engine, BoundedEngine):
        raise RequestError(ErrorCode.BAD_REQUEST, "this scene's engine cannot check 'strict'")
    items = [("load", i, ld.at) for i, ld in enumerate(loads)]
    items += [("probe", i, pr.at) for i, pr in enumerate(probes)]
    items += [("grasp", i, g.at) for i, g in enumerate(grasps)]
    items += [("tool", i, tl.at) for i, tl in enumerate(tools)]
    for kind, index, at in items:
        if not engine.contains(at):
            where = ", ".join(f"{x:.6g}" for x in at)
            raise RequestError(
                ErrorCode.BAD_REQUEST,
                f"{kind} {index}: at ({where}) lies outside the domain "
                f"{engine.domain_text()} (strict)",
            )


def _require_inputs(engine: LiveEngine[Any], **given: object) -> None:
    """Refuse what the engine does not take (``LiveEngine.inputs``) before it reaches it."""
    for name, value in given.items():
        if value and name not in engine.inputs:
            takes = ", ".join(sorted(engine.inputs)) or "nothing"
            raise RequestError(
                ErrorCode.BAD_REQUEST, f"this scene's engine takes no {name} (it takes {takes})"
            )


def _start(engine: LiveEngine[Any], initial: dict[str, Any] | None) -> Start[Any]:
    _require_inputs(engine, initial=initial)
    try:
        shapes = Initial.from_wire(initial)
    except LiveInputError as exc:
        raise wire_error(exc) from None
    try:
        return engine.start(shapes.displacement, shapes.velocity)
    except LiveError as exc:
        raise wire_error(exc, "initial: ") from None
