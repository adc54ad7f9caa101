"""The ``steps`` op: several sessions' steps in one request are the single steps bit for bit
(64 sessions, frames and readings), each taken exactly once (a re-sent batch is answered from
the store), a refused item stops no other, and a batch past its bounds is refused whole."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from membrane_client import Client, ServerError
from membrane_client.protocol import MAX_BATCH_STEPS, Request, RequestError, encode
from membrane_client.session import Load, Probe, step_many
from membrane_server.server import Server

SESSIONS, ROUNDS = 64, 8


@pytest.fixture
def server(many_sessions_server: Server) -> Server:
    return many_sessions_server


def _inputs(index: int, k: int) -> dict[str, Any]:
    """Each session's own step: a load somewhere of its own, a probe on every third."""
    at = (0.1 + 0.012 * index, 0.2 + 0.009 * index)
    options: dict[str, Any] = {"loads": [Load(at, -0.3 * (1 + k % 3), 0.05)], "frame": True}
    if index % 3 == 0:
        options["probes"] = [Probe((0.5, 0.5), 0.002 * (k % 4), 0.05)]
    return options


def test_64_sessions_stepped_in_batches_are_the_single_steps_bit_for_bit(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        single = [client.session("membrane-live") for _ in range(SESSIONS)]
        batched = [client.session("membrane-live") for _ in range(SESSIONS)]
        for k in range(ROUNDS):
            alone = [s.step(**_inputs(i, k)) for i, s in enumerate(single)]
            together = step_many(client, [(s, _inputs(i, k)) for i, s in enumerate(batched)])
            for one, many in zip(alone, together, strict=True):
                assert not isinstance(many, ServerError), many
                assert one.z is not None and many.z is not None
                assert one.z.tobytes() == many.z.tobytes() and one.probes == many.probes
        assert [s.k for s in batched] == [ROUNDS] * SESSIONS
        moved = alone[0].z
        assert moved is not None and np.abs(moved).max() > 1e-4  # the inputs moved the tissue


def test_a_resent_batch_is_answered_from_the_store_not_taken_again(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        sessions = [client.session("membrane-live") for _ in range(4)]
        first = step_many(client, [(s, _inputs(i, 0)) for i, s in enumerate(sessions)])
        for session in sessions:
            session.k = 0  # as after a lost reply: the same steps again
        again = step_many(client, [(s, _inputs(i, 0)) for i, s in enumerate(sessions)])
        for a, b in zip(first, again, strict=True):
            assert not isinstance(a, ServerError) and not isinstance(b, ServerError)
            assert a.z is not None and b.z is not None and a.z.tobytes() == b.z.tobytes()
        live = client.stats().live
        assert live is not None and live["steps"] == 4 and live["resent"] == 4


def test_a_refused_item_stops_no_other(server: Server) -> None:
    with Client(server.address, timeout=10.0) as client:
        good, bad = client.session("membrane-live"), client.session("membrane-live")
        results = step_many(
            client, [(bad, {"probes": [Probe((0.5, 0.5), 0.01, 1e-4)]}), (good, {"frame": False})]
        )
        assert isinstance(results[0], ServerError) and results[0].code == "bad_request"
        assert "steps item 0" in results[0].message and bad.k == 0
        assert not isinstance(results[1], ServerError) and good.k == 1
        other = Client(server.address, timeout=10.0)
        with pytest.raises(Exception, match="belongs to another client"):
            step_many(other, [(good, {})])
        other.close()
        raw = client.request("steps", steps=[{"k": 0}, "x", {"session": good.id, "k": 1}])
        assert len(raw["steps"]) == 3


@pytest.mark.parametrize(
    ("steps", "says"),
    [
        ([], "'steps' must be a list of 1 to"),
        ("x", "'steps' must be a list of 1 to"),
        ([{"session": "s", "k": 0}] * (MAX_BATCH_STEPS + 1), "'steps' must be a list of 1 to"),
        ([{"session": "s", "k": 0, "repeat": 32}] * 9, f"at most {MAX_BATCH_STEPS} steps in all"),
    ],
)
def test_a_batch_past_its_bounds_is_refused_whole(steps: Any, says: str) -> None:
    raw = {"v": 1, "id": 3, "op": "steps", "steps": steps}
    with pytest.raises(RequestError, match=says):
        Request.from_wire(encode(raw))


def test_a_session_steps_alike_alone_and_in_a_batch_of_one(server: Server) -> None:
    """The batched path at width 1 is the single step's."""
    with Client(server.address, timeout=10.0) as client:
        a, b = client.session("membrane-live"), client.session("membrane-live")
        for k in range(5):
            one = a.step(**_inputs(0, k))
            (many,) = step_many(client, [(b, _inputs(0, k))])
            assert not isinstance(many, ServerError)
            assert one.z is not None and many.z is not None and one.z.tobytes() == many.z.tobytes()
