"""The ``step_columns`` op: many sessions' steps of loads alone as columns are the lone steps bit
for bit (64 sessions, frames), each taken exactly once (a re-sent request, or a lone ``step``
re-send of one of its steps, is answered from the store), a refused session stops no other,
and columns out of form are refused whole."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from membrane_client import Client, ServerError
from membrane_client.protocol import (
    MAX_BATCH_STEPS,
    Request,
    RequestError,
    StepColumns,
    decode,
    encode,
    unpack_array,
)
from membrane_client.session import Load, Session, step_columns
from membrane_server.server import Server

SESSIONS, ROUNDS = 64, 6


@pytest.fixture
def server(many_sessions_server: Server) -> Server:
    return many_sessions_server


def _rows(k: int, count: int = SESSIONS) -> np.ndarray:
    """Each session's own load this round: (sessions, 1 load, x y force radius)."""
    index = np.arange(count)
    return np.stack(
        [0.1 + 0.012 * index, 0.2 + 0.009 * index, -0.3 * (1 + (index + k) % 3),
         np.full(count, 0.05)], axis=1,
    )[:, None, :]  # fmt: skip


def _lone(session: Session, row: np.ndarray, frame: bool) -> Any:
    x, y, force, radius = (float(v) for v in row[0])
    return session.step(loads=[Load((x, y), force, radius)], frame=frame)


def test_64_sessions_stepped_as_columns_are_the_lone_steps_bit_for_bit(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        alone = [client.session("membrane-live") for _ in range(SESSIONS)]
        columns = [client.session("membrane-live") for _ in range(SESSIONS)]
        for k in range(ROUNDS):
            frames = [(i + k) % 3 == 0 for i in range(SESSIONS)]
            rows = _rows(k)
            lone = [_lone(s, rows[i], frames[i]) for i, s in enumerate(alone)]
            out = step_columns(client, columns, rows, frames=frames)
            assert not out.refused
            assert out.k.tolist() == [one.k for one in lone] == [k + 1] * SESSIONS
            assert out.t.tolist() == [one.t for one in lone]
            assert out.framed.tolist() == [i for i in range(SESSIONS) if frames[i]]
            for row, index in enumerate(out.framed):
                assert out.z[row].tobytes() == np.asarray(lone[index].z).tobytes()
        assert [s.k for s in columns] == [ROUNDS] * SESSIONS
        assert np.abs(out.z).max() > 1e-4  # the loads moved the tissue


def test_a_resent_request_and_a_lone_resend_are_answered_from_the_store(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        sessions = [client.session("membrane-live") for _ in range(4)]
        twin = client.session("membrane-live")
        first = step_columns(client, sessions, _rows(0, 4))
        lone = _lone(twin, _rows(0, 4)[0], True)
        for session in sessions:
            session.k = 0  # as after a lost reply: the same steps again
        again = step_columns(client, sessions, _rows(0, 4))
        assert again.k.tolist() == first.k.tolist() == [1] * 4
        assert again.z.tobytes() == first.z.tobytes()
        # A lone step re-send of session 0's step: the reply a lone step would have had.
        resent = client.request("step", session=sessions[0].id, token=sessions[0].token, k=0,
                                scene="membrane-live", loads=[])  # fmt: skip
        reference = client.request("read", session=twin.id, token=twin.token)
        assert resent["k"] == lone.k == 1 and resent["t"] == lone.t
        assert resent["z"] == reference["z"] and resent["revision"] == reference["revision"]
        live = client.stats().live
        assert live is not None and live["resent"] == 5


def test_a_refused_session_stops_no_other(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        sessions = [client.session("membrane-live") for _ in range(5)]
        sessions[1].k = 7  # a wrong k
        rows = _rows(0, 5)
        rows[2, 0, 2] = np.nan  # a force the engine refuses
        rows[3, 0, 0] = 1.5  # a centre outside the domain
        stranger = Session(client, "membrane-live", "never-opened")
        out = step_columns(client, [*sessions, stranger], np.concatenate([rows, rows[:1]]))
        assert sorted(out.refused) == [1, 2, 3, 5]
        codes = {i: error.code for i, error in out.refused.items()}
        assert codes == {1: "step_mismatch", 2: "bad_request", 3: "bad_request",
                         5: "unknown_session"}  # fmt: skip
        assert "session 2: load 0 force must be finite" in out.refused[2].message
        assert out.k.tolist() == [1, -1, -1, -1, 1, -1]
        assert sessions[0].k == sessions[4].k == 1 and sessions[2].k == 0
        # The refused sessions were left as they were: their step 0 is still to take.
        retry = step_columns(client, sessions[2:4], _rows(0, 2))
        assert not retry.refused and retry.k.tolist() == [1, 1]


def _columns(**change: Any) -> dict[str, Any]:
    sessions = ["a", "b"]
    message = StepColumns(sessions, [0, 0], [None, None], _rows(0, 2), [True, True]).to_wire()
    return {"v": 1, "id": 1, "op": "step_columns", **message, **change}


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"sessions": ["a", "a"]}, "at most once"),
        ({"sessions": []}, "'sessions' must be a list of 1 to"),
        ({"sessions": ["x"] * (MAX_BATCH_STEPS + 1)}, "'sessions' must be a list of 1 to"),
        ({"k": [0]}, "'k' must be a list of 2 ints"),
        ({"k": [0, -1]}, "'k' must be a list of 2 ints"),
        ({"tokens": ["t"]}, "'tokens' must be a list of 2"),
        ({"frames": [True]}, "'frames' must be true, false or 2"),
        ({"loads": "x"}, "'loads': an array must be a map"),
        ({"loads": {"dtype": "<f8", "shape": [2, 4], "data": bytes(64)}}, "'loads' must be an"),
        ({"dtype": "<i4"}, "'dtype' must be one of"),
    ],
)
def test_columns_out_of_form_are_refused_whole(change: dict[str, Any], says: str) -> None:
    with pytest.raises(RequestError, match=says) as refused:
        Request.from_wire(encode(_columns(**change)))
    assert refused.value.code == "bad_request"


def test_the_scene_must_batch_and_the_rows_fit_it(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        sessions = [client.session("membrane-live") for _ in range(2)]
        with pytest.raises(ServerError, match="4 numbers, got 3"):
            step_columns(client, sessions, np.zeros((2, 1, 3)))
        assert [s.k for s in sessions] == [0, 0]
        message = decode(Request("step_columns", 9, scene="nope", columns=StepColumns(
            ["a"], [0], [None], np.zeros((1, 0, 4)), [True])).to_wire())  # fmt: skip
        assert message["scene"] == "nope"
        with pytest.raises(ServerError, match="unknown_scene"):
            client.request("step_columns", scene="nope", columns=StepColumns(
                ["a"], [0], [None], np.zeros((1, 0, 4)), [True]))  # fmt: skip


def test_a_session_of_an_earlier_revision_is_refused_alone_before_any_step() -> None:
    """After a reload a session stays on the scene it opened on (another lattice, perhaps): it
    is refused, and nothing of the request was stepped first."""
    from membrane_server.dispatch import Dispatcher
    from membrane_server.served import ServedScene
    from membrane_server.sessions import SessionTable

    table = SessionTable(8, 60.0, max_per_peer=8)
    before = Dispatcher([ServedScene.load("membrane-live")], sessions=table)
    after = Dispatcher([ServedScene.load("membrane-live")], sessions=table)  # the reload's
    for dispatcher, session in ((before, "old"), (after, "new")):
        opened = dispatcher.handle([Request("open", 1, session=session).to_wire()], "p")
        assert decode(opened.reply)["ok"]
    columns = StepColumns(["old", "new"], [0, 0], [None, None], _rows(0, 2), [True, True])
    reply = decode(after.handle([Request("step_columns", 2, columns=columns).to_wire()], "p").reply)
    assert reply["ok"] and reply["k"] == [-1, 1] and reply["framed"] == [1]
    assert reply["refused"][0][:2] == [0, "bad_request"]
    assert "earlier revision" in reply["refused"][0][2]
    assert table.get("old", "p").k == 0  # type: ignore[union-attr]


def test_a_resend_that_asks_a_frame_its_step_did_not_send_gets_its_end(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        session = client.session("membrane-live")
        step_columns(client, [session], _rows(0, 1), frames=False)
        session.k = 0  # the same step again, this time with its frame
        again = step_columns(client, [session], _rows(0, 1), frames=True)
        read = client.request("read", session=session.id, token=session.token)
        assert again.k.tolist() == [1] and again.framed.tolist() == [0]
        assert again.z[0].tobytes() == unpack_array(read["z"]).tobytes()


def test_an_empty_array_whose_axes_pass_numpys_bounds_is_refused_in_one_line() -> None:
    loads = {"dtype": "<f8", "shape": [2, 0, 2**62], "data": b""}
    with pytest.raises(RequestError, match="beyond numpy's bounds") as refused:
        Request.from_wire(encode(_columns(loads=loads)))
    assert refused.value.code == "bad_request"
