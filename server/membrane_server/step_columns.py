"""The ``step_columns`` op: many sessions' steps of loads alone, as columns.

A client that runs many environments (a reinforcement-learning gym) steps all of them every
tick under loads alone. The ``steps`` op already takes them in one request, but each item is a
``step`` map read, checked and answered by itself: per item, about as much Python as the step's
own arithmetic. Here the request is columns (the sessions, their k and tokens, one array of
every load, the frame flags) and so is the reply (each session's k and t, one array of the
frames sent), so what is left per session is its own step (``BatchedEngine.step_loads``, the
same call a lone step of loads makes: the same bits by construction) and its bookkeeping.

Each session's step is still a ``step``: taken exactly once (its k and token; a re-sent request
is answered from each session's store), refused alone (an unknown session, a wrong k, a load
the engine refuses: the others are taken). What is stored for a re-send is the step's values
(``ColumnStep``); the reply a lone ``step`` re-send of it would get is encoded only if one asks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from membrane_client.live_schema import LiveStepReply
from membrane_client.protocol import (
    ErrorCode,
    Request,
    RequestError,
    StepColumns,
    decode,
    encode,
    ok_reply,
    pack_array,
    unpack_array,
)
from membrane_models.live import LiveError, Load
from membrane_models.live.interface import BatchedEngine
from membrane_server.sessions import LiveSession, Sent, StoredStep

if TYPE_CHECKING:
    from membrane_server.served import ServedScene
    from membrane_server.sessions import SessionTable

__all__ = ["ColumnStep", "step_columns"]


@dataclass(frozen=True, slots=True)
class ColumnStep:
    """A step taken in a ``step_columns`` request, kept as its values (``StoredStep``).

    Attributes:
        token, request_id: what tells a re-send (``SessionTable.resent_step``).
        k, t: the session's step count and time after it.
        frame: the frame as sent (in ``dtype``, lattice-shaped), or None when none was asked.
        session, revision: the session's id and its scene's revision.
    """

    token: str | None
    request_id: int
    k: int
    t: float
    frame: np.ndarray | None
    dtype: str
    session: str
    revision: str

    def reply_to(self, request: Request) -> bytes:
        """The reply a lone ``step`` of these values would have had (under ``request``'s id)."""
        fields = LiveStepReply(
            session=self.session, k=self.k, t=self.t, revision=self.revision, probes=(),
            grasps=(), tools=(), z=self.frame, token=None, dtype=self.dtype,
        ).to_reply_fields()  # fmt: skip
        return encode(ok_reply(request.id, **fields))


class _Columns:
    """The reply's columns as they fill: each session's k and t (-1 and NaN where refused),
    the frames sent, and the refusals ([index, code, message])."""

    def __init__(self, n: int) -> None:
        self.k, self.t = [-1] * n, [math.nan] * n
        self.frames: dict[int, np.ndarray] = {}
        self.refused: list[list[Any]] = []

    def took(self, index: int, k: int, t: float, frame: np.ndarray | None) -> None:
        self.k[index], self.t[index] = k, t
        if frame is not None:
            self.frames[index] = frame

    def refuse(self, index: int, error: RequestError) -> None:
        self.refused.append([index, str(error.code), str(error)])

    def fields(self, served: ServedScene, dtype: str) -> dict[str, Any]:
        framed = sorted(self.frames)
        if framed:
            z = np.stack([self.frames[i] for i in framed])
        else:
            z = np.empty((0, *served.shape), dtype=dtype)
        return {
            "k": self.k,
            "t": self.t,
            "framed": framed,
            "z": pack_array(z, dtype),
            "refused": sorted(self.refused),
            "revision": served.revision,
        }


def step_columns(
    table: SessionTable, served: ServedScene, request: Request, peer: str
) -> dict[str, Any]:
    """The reply's fields to a ``step_columns`` request on ``served`` (module docstring).

    Raises:
        RequestError: the whole request refused (a scene that is not live, or whose engine
            steps one session at a time; loads whose rows are not the scene's width).
    """
    columns = request.columns
    assert columns is not None  # the protocol reads them for this op
    live = served.live
    if live is None:
        raise RequestError(ErrorCode.NOT_LIVE, f"scene {served.name} is a film, not live")
    engine: object = live
    if not isinstance(engine, BatchedEngine):
        reason = f"scene {served.name} steps its sessions one at a time: send 'steps' instead"
        raise RequestError(ErrorCode.BAD_REQUEST, reason)
    dims = live.spatial_dims
    if columns.loads.shape[2] != dims + 2:
        reason = (
            f"'loads' rows on scene {served.name} are (centre ({dims} numbers), force, radius): "
            f"{dims + 2} numbers, got {columns.loads.shape[2]}"
        )
        raise RequestError(ErrorCode.BAD_REQUEST, reason)
    answer = _Columns(len(columns.sessions))
    taken = _take_all(table, served, request, peer, dims, answer)
    if taken:
        _step_batch(table, engine, taken, request, columns, answer)
    return answer.fields(served, request.dtype)


_Taken = tuple[int, LiveSession, tuple[Load, ...]]


def _take_all(
    table: SessionTable,
    served: ServedScene,
    request: Request,
    peer: str,
    dims: int,
    answer: _Columns,
) -> list[_Taken]:
    """Each session checked (open, on this scene, its k): ready to step with its loads, or
    answered from its store (a re-send), or refused."""
    columns = request.columns
    assert columns is not None
    rows = columns.loads.tolist()  # Python floats, as a lone step's loads are read
    taken: list[_Taken] = []
    for index, session_id in enumerate(columns.sessions):
        try:
            session = table.require(session_id, peer)
            _require_on(session, served, index)
            k = columns.k[index]
            if k != session.k:  # a re-send (its stored values), or the mismatch refusal
                last = table.resent_step(session, k, columns.tokens[index], request.id)
                stored = _stored_values(last)
                frame = None
                if columns.frames[index]:  # the stored step's, or its end's (its state now)
                    frame = stored[2]
                    if frame is None:
                        frame = _sent_frame(session.engine.frame(session.state), session, request)
                answer.took(index, stored[0], stored[1], frame)
                continue
        except RequestError as exc:
            answer.refuse(index, exc)
            continue
        loads = tuple([Load(tuple(row[:dims]), row[dims], row[dims + 1]) for row in rows[index]])
        taken.append((index, session, loads))
    return taken


def _require_on(session: LiveSession, served: ServedScene, index: int) -> None:
    """Refuse a session on another scene, or on an earlier revision of this one (opened before
    a reload: its lattice and engine may differ from the columns' scene)."""
    if session.served is served:
        return
    if session.served.name != served.name:
        reason = f"session {index} is on scene {session.served.name}, not {served.name}"
    else:
        reason = (
            f"session {index} opened on an earlier revision of scene {served.name} (reloaded "
            "since): step it with 'step' or 'steps', or open a new session"
        )
    raise RequestError(ErrorCode.BAD_REQUEST, reason)


def _sent_frame(frame: np.ndarray, session: LiveSession, request: Request) -> np.ndarray:
    """A frame as sent: in the request's dtype, lattice-shaped."""
    return np.asarray(frame, dtype=np.dtype(request.dtype)).reshape(session.served.shape)


def _stored_values(last: StoredStep) -> tuple[int, float, np.ndarray | None]:
    """k, t and the frame of a stored step (a lone step's reply is read back)."""
    if isinstance(last, ColumnStep):
        return last.k, last.t, last.frame
    assert isinstance(last, Sent)  # the two kinds of stored step
    reply = decode(last.reply)
    frame = None if "z" not in reply else unpack_array(reply["z"])
    return int(reply["k"]), float(reply["t"]), frame


def _step_batch(
    table: SessionTable,
    engine: BatchedEngine,
    batch: Sequence[_Taken],
    request: Request,
    columns: StepColumns,
    answer: _Columns,
) -> None:
    """Step the taken sessions as one engine call and record each one's step."""
    results = engine.step_loads(
        [session.state for _, session, _ in batch],
        [loads for _, _, loads in batch],
        [columns.frames[index] for index, _, _ in batch],
    )
    for (index, session, _), result in zip(batch, results, strict=True):
        if isinstance(result, LiveError):
            answer.refuse(index, RequestError(ErrorCode.BAD_REQUEST, f"session {index}: {result}"))
            continue
        session.apply(result)
        table.counts["steps"] += 1
        frame = None if result.frame is None else _sent_frame(result.frame, session, request)
        session.last_step = ColumnStep(
            columns.tokens[index], request.id, session.k, session.t, frame, request.dtype,
            columns.sessions[index], session.served.revision,
        )  # fmt: skip
        answer.took(index, session.k, session.t, frame)
