"""Live sessions: a robot's loads and probes reach the tissue, step by step (docs/PROTOCOL.md,
"Live sessions").

```python
with Client(address) as client, client.session("membrane-live") as session:
    frame = session.step(probes=[Probe((0.5, 0.5), depth=0.001, radius=0.05)])
    frame.probes[0].force, frame.positions()
```

Each Session has its own random id (the envelope's ``session``); one Client may hold several.
A step carries the index ``k`` it expects to take, so a step the Lazy Pirate re-sends is
answered from the server's stored reply, never applied twice. Each Session object also sends
its own random ``token`` on every live op: the server tells a re-send by the token, op and k,
so two clients whose request ids coincide are never taken for one client re-sending.

``Load``, ``Probe``, ``ProbeReading`` and the replies are the live schema's (``live_schema``).
"""

from __future__ import annotations

import secrets
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from membrane_client.errors import MembraneError, ProtocolError, ServerError, StepLost, Timeout
from membrane_client.frame import SceneInfo
from membrane_client.live_schema import (
    Grasp,
    GraspReading,
    Initial,
    LiveStepReply,
    Load,
    OpenReply,
    Probe,
    ProbeReading,
    ResetReply,
    Tool,
    ToolReading,
)
from membrane_client.protocol import Op, StepColumns, read_reply, unpack_array

if TYPE_CHECKING:
    from membrane_client.client import Client

__all__ = [
    "ColumnFrames",
    "Grasp",
    "GraspReading",
    "LiveFrame",
    "Load",
    "Probe",
    "ProbeReading",
    "Session",
    "Tool",
    "ToolReading",
    "step_columns",
    "step_many",
]


@dataclass(frozen=True, eq=False)
class LiveFrame:
    """A live session's state after step ``k`` (time ``t``): the frame and the probes' readings."""

    k: int
    t: float
    z: np.ndarray | None  # shaped like the lattice; None when the step asked for no frame
    probes: tuple[ProbeReading, ...]
    info: SceneInfo | None = None
    grasps: tuple[GraspReading, ...] = ()  # one per grasp of the step, in order
    tools: tuple[ToolReading, ...] = ()  # one per tool of the step, in order

    def positions(self) -> np.ndarray:
        """(n, 3) world coordinates of every sphere (needs the frame and the description)."""
        if self.z is None or self.info is None:
            raise ProtocolError("this step carried no frame (step(..., frame=True) sends one)")
        return self.info.positions(self.z)

    @classmethod
    def from_reply(cls, reply: dict[str, Any], info: SceneInfo | None) -> LiveFrame:
        """From a ``step`` or ``read`` reply (``live_schema.LiveStepReply``)."""
        read = LiveStepReply.from_reply(reply)
        return cls(read.k, read.t, read.z, read.probes, info, read.grasps, read.tools)


class Session:
    """A live session on one scene (open it with ``Client.session``). Not thread-safe.

    Attributes:
        id: The session's id on the wire (random unless given, to join an open session).
        token: This object's own random token (sent on every live op; re-sends carry it).
        k: Steps taken so far (the index of the next step).
        residuals: How far the initial shapes were from what the modes carry (relative).
    """

    def __init__(self, client: Client, scene: str | None = None, session_id: str | None = None):
        self.client, self.scene = client, scene
        self.id = session_id or uuid.uuid4().hex
        self.token = secrets.token_hex(16)
        self.k = 0
        self.residuals: dict[str, float] = {}
        self.info: SceneInfo | None = None
        self.closed = False

    def open(
        self, displacement: ArrayLike | None = None, velocity: ArrayLike | None = None
    ) -> Session:
        """Start the session from rest, or from shapes on the lattice (sent as float32)."""
        initial = Initial(_array(displacement), _array(velocity)).to_wire()
        opened = OpenReply.from_reply(self._request(Op.OPEN, initial=initial))
        self.k, self.residuals = opened.k, opened.residuals
        self.info = self.client.describe(self.scene)
        return self

    def step(
        self,
        loads: Any = (),
        probes: Any = (),
        *,
        frame: bool = True,
        strict: bool = False,
        dtype: str = "<f4",
        grasps: Any = (),
        tools: Any = (),
        lookahead: bool = False,
        repeat: int = 1,
    ) -> LiveFrame:
        """Take step ``k`` under ``loads``, ``probes``, ``grasps`` and ``tools``
        (Load/Probe/Grasp/Tool or their maps; a grasp holds the tissue at its height,
        ``LiveFrame.grasps`` the force; a rigid tool presses its shape in, ``LiveFrame.tools``
        what it felt).

        ``strict``: an item centred outside the scene's domain is refused (a
        ``ServerError`` naming the domain's extent) instead of touching nothing. ``dtype``:
        the frame's element type, ``"<f4"`` or ``"<f8"`` (to check a surface beyond float32's
        6e-8). ``lookahead``: each probe's reading also gives ``next_free``, the next step's
        free displacement under it, from which a haptic loop renders that step's force at any
        depth before it is taken (``membrane_client.haptics``; loads and probes only).
        ``repeat``: take that many steps (1 to ``protocol.MAX_REPEAT``) under the same inputs in
        one round trip, the frame and readings the last one's (a display at 60 frames/s of a
        1 kHz scene: 17 steps a request, not 17 requests).

        Raises:
            StepLost: no reply on any retry; ``applied`` says whether the server took the step
                (``k`` follows the server's count either way, so the next step is in step).
        """
        fields = _step_fields(
            loads, probes, grasps, tools, frame=frame, strict=strict, lookahead=lookahead,
            repeat=repeat,
        )  # fmt: skip
        try:
            reply = self._request(Op.STEP, k=self.k, dtype=dtype, **fields)
        except Timeout as lost:
            raise self._lost_step(lost) from lost
        result = LiveFrame.from_reply(reply, self.info)
        self.k = result.k
        return result

    def frame(self, dtype: str = "<f4") -> LiveFrame:
        """The session's current frame (a display loop beside a haptic one)."""
        return LiveFrame.from_reply(self._request(Op.READ, dtype=dtype), self.info)

    def _lost_step(self, lost: Timeout) -> StepLost:
        """What became of step ``k`` whose every reply was lost. ``read`` gives the server's
        count and the token of the step its state follows: at k + 1 with this object's token,
        the step was ours; still at k, nobody took it; at k + 1 with another token, another
        Session took step k (it is taken once); further on, the server cannot tell."""
        asked = self.k
        head = f"step k = {asked}: {lost}; "
        try:
            state = LiveStepReply.from_reply(self._request(Op.READ))
        except Timeout:
            unknown = "a read got no reply either: whether the server took the step is unknown"
            return StepLost(head + unknown, None, None)
        self.k = state.k
        if state.k == asked + 1 and state.token == self.token:
            taken = "the server took it (its frame is lost: frame() reads the state)"
            return StepLost(f"{head}{taken}; next k = {state.k}", True, state.k)
        if state.k == asked or state.k == asked + 1:
            return StepLost(f"{head}the server did not take it; next k = {state.k}", False, state.k)
        moved = "another peer stepped the session since: whether the server took it is unknown"
        return StepLost(f"{head}{moved}; next k = {state.k}", None, state.k)

    def reset(self) -> None:
        """Back to the initial state, step 0."""
        self.k = ResetReply.from_reply(self._request(Op.RESET)).k

    def close(self) -> None:
        """End the session on the server. Safe to call twice."""
        if not self.closed and not self.client.closed:
            self._request(Op.CLOSE)
        self.closed = True

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _request(self, op: str, **fields: Any) -> dict[str, Any]:
        return self.client.request(
            op, scene=self.scene, session=self.id, token=self.token, **fields
        )


def step_many(
    client: Client, items: Sequence[tuple[Session, Mapping[str, Any]]]
) -> list[LiveFrame | ServerError]:
    """Several sessions' steps in one request (the ``steps`` op: one receive, decode and reply
    on the server for all of them, a client of many environments): each item is a Session of
    this client and its step's keyword arguments as ``Session.step`` takes them (``loads``,
    ``probes``, ``grasps``, ``tools``, ``frame``, ``repeat``, ``dtype``, ``strict``). Every
    session's step is taken exactly once, as by ``step``; the results come in the items' order,
    a ``ServerError`` in place of a step the server refused (the others are taken).

    Raises:
        Timeout: no reply on any retry (re-sent, every step already taken is answered from the
            server's store, not taken again); MembraneError: a session of another client.
    """
    wire = []
    for session, options in items:
        if session.client is not client:
            raise MembraneError(f"session {session.id} belongs to another client")
        kwargs = dict(options)
        dtype = kwargs.pop("dtype", "<f4")
        fields = _step_fields(
            kwargs.pop("loads", ()), kwargs.pop("probes", ()), kwargs.pop("grasps", ()),
            kwargs.pop("tools", ()), **kwargs,
        )  # fmt: skip
        item = {"session": session.id, "token": session.token, "k": session.k, **fields}
        if session.scene is not None:
            item["scene"] = session.scene
        wire.append(item if dtype == "<f4" else {**item, "dtype": dtype})
    reply = client.request(Op.STEPS, steps=wire)
    results: list[LiveFrame | ServerError] = []
    for (session, _), data in zip(items, reply["steps"], strict=True):
        try:  # each item's reply is a whole reply to this request, checked as one
            message = read_reply(data, reply["id"])
        except ServerError as refused:
            results.append(refused)
            continue
        frame = LiveFrame.from_reply(message, session.info)
        session.k = frame.k
        results.append(frame)
    return results


class ColumnFrames(NamedTuple):
    """What a ``step_columns`` request gave, session by session in the order sent.

    Attributes:
        k: (sessions,) each session's steps taken after this request (-1 where refused).
        t: (sessions,) each session's time, k dt (NaN where refused).
        framed: (frames,) the indices of the sessions whose frame was sent.
        z: (frames, *lattice) those frames, in ``framed``'s order.
        refused: the refused sessions' indices and the server's reasons.
        revision: the scene's revision.
    """

    k: np.ndarray
    t: np.ndarray
    framed: np.ndarray
    z: np.ndarray
    refused: dict[int, ServerError]
    revision: str


def step_columns(
    client: Client,
    sessions: Sequence[Session],
    loads: ArrayLike,
    frames: bool | np.bool_ | Sequence[bool] = True,
    dtype: str = "<f4",
) -> ColumnFrames:
    """Many sessions' steps under loads alone, in one request of columns (the ``step_columns``
    op, docs/PROTOCOL.md): ``loads[i]`` is session i's loads, rows of (centre, force, radius) in
    the scene's units, ``(sessions, loads, dims + 2)`` (or ``(sessions, dims + 2)``: one load
    each). Each session's step is the ``step`` it stands for, bit for bit, taken exactly once;
    a refused one (``refused``) stops no other. The sessions are this client's, on one scene,
    each at most once.

    Raises:
        Timeout: no reply on any retry (a re-sent request is answered from the sessions'
            stores, never taken twice); ServerError: the request refused whole; MembraneError:
            a session of another client or another scene.
    """
    rows = np.asarray(loads, dtype=np.float64)
    if rows.ndim == 2:
        rows = rows[:, None, :]
    scenes = {session.scene for session in sessions}
    if any(session.client is not client for session in sessions) or len(scenes) > 1:
        raise MembraneError("step_columns takes sessions of this client on one scene")
    if isinstance(frames, bool | np.bool_):
        flags = [bool(frames)] * len(sessions)
    else:
        flags = [bool(f) for f in frames]
    columns = StepColumns(
        [s.id for s in sessions], [s.k for s in sessions], [s.token for s in sessions], rows, flags
    )
    reply = client.request(Op.STEP_COLUMNS, scene=scenes.pop() if scenes else None,
                           columns=columns, dtype=dtype)  # fmt: skip
    try:
        ks, framed = np.asarray(reply["k"], dtype=np.int64), np.asarray(reply["framed"], np.intp)
        answer = ColumnFrames(
            ks, np.asarray(reply["t"], dtype=np.float64), framed, unpack_array(reply["z"]),
            {int(i): ServerError(str(code), str(message)) for i, code, message in reply["refused"]},
            str(reply["revision"]),
        )  # fmt: skip
    except (KeyError, TypeError, ValueError) as exc:
        raise ProtocolError(f"a step_columns reply is malformed: {exc}") from None
    if ks.shape != (len(sessions),) or answer.z.shape[:1] != framed.shape:
        raise ProtocolError("a step_columns reply's columns do not match its sessions")
    for session, k in zip(sessions, ks.tolist(), strict=True):
        if k >= 0:
            session.k = k
    return answer


def _step_fields(
    loads: Any,
    probes: Any,
    grasps: Any,
    tools: Any,
    *,
    frame: bool = True,
    strict: bool = False,
    lookahead: bool = False,
    repeat: int = 1,
) -> dict[str, Any]:
    """A step request's fields from ``Session.step``'s arguments."""
    fields: dict[str, Any] = dict(
        loads=[_wire(item) for item in loads],
        probes=[_wire(item) for item in probes],
        frame=frame,
        strict=strict,
    )
    if grasps:
        fields["grasps"] = [_wire(item) for item in grasps]
    if tools:
        fields["tools"] = [_wire(item) for item in tools]
    if lookahead:
        fields["lookahead"] = True
    if repeat != 1:
        fields["repeat"] = repeat
    return fields


def _wire(item: Any) -> Any:
    return item.to_wire() if isinstance(item, Load | Probe | Grasp | Tool) else item


def _array(values: ArrayLike | None) -> np.ndarray | None:
    return None if values is None else np.asarray(values)
