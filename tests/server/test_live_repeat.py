"""A step's ``repeat``: n steps under the same inputs in one request are the n single steps, bit
for bit (the frame and the readings the last one's); a re-send is answered, not applied again;
a bad count is refused and leaves the session where it was."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from membrane_client import Client, ServerError
from membrane_client.protocol import MAX_REPEAT, Request, RequestError, encode
from membrane_client.session import Grasp, Probe, Tool

AT = (0.5, 0.5)
INPUTS: list[dict[str, Any]] = [
    {"probes": [Probe(AT, 0.01, 0.05)]},
    {"tools": [Tool("sphere", AT, 0.02, 0.1)]},
    {"grasps": [Grasp(AT, 0.01, 0.05)]},
]


@pytest.mark.parametrize("inputs", INPUTS, ids=["probe", "tool", "grasp"])
def test_repeated_steps_are_the_single_steps_bit_for_bit(
    start_server: Any, inputs: dict[str, Any]
) -> None:
    server = start_server(["membrane-live"])
    with Client(server.address) as client:
        with client.session("membrane-live") as single:
            for _ in range(16):
                one = single.step(frame=False, **inputs)
            one = single.step(frame=True, **inputs)
        with client.session("membrane-live") as batched:
            first = batched.step(frame=False, repeat=9, **inputs)
            many = batched.step(frame=True, repeat=8, **inputs)
    assert first.k == 9 and first.z is None and many.k == one.k == 17
    assert one.z is not None and many.z is not None
    assert many.z.tobytes() == one.z.tobytes()
    assert (many.probes, many.tools, many.grasps) == (one.probes, one.tools, one.grasps)
    assert np.abs(one.z).max() > 1e-3  # the inputs moved the tissue


def test_a_resent_repeated_step_is_answered_not_applied_again(start_server: Any) -> None:
    server = start_server(["membrane-live"])
    with Client(server.address) as client, client.session("membrane-live") as session:
        session.step(frame=False, repeat=5)
        session.k = 0  # as after a lost reply: the step is sent again
        again = session.step(frame=False, repeat=5)
        assert again.k == 5 == session.k
        live = client.stats().live
        assert live is not None and live["steps"] == 5
        with pytest.raises(ServerError, match="the next step is k = 5"):
            session.k = 1
            session.step(frame=False)


@pytest.mark.parametrize("repeat", [0, -1, MAX_REPEAT + 1, 2.0, True, "4", None])
def test_a_bad_repeat_is_refused(repeat: Any) -> None:
    raw = {"v": 1, "id": 3, "op": "step", "session": "s", "k": 0, "repeat": repeat}
    with pytest.raises(RequestError, match=rf"'repeat' must be an int in \[1, {MAX_REPEAT}\]"):
        Request.from_wire(encode(raw))


def test_a_refused_repeated_step_leaves_the_session_where_it_was(start_server: Any) -> None:
    server = start_server(["membrane-live"])
    with Client(server.address) as client, client.session("membrane-live") as session:
        with pytest.raises(ServerError, match=r"radius 0\.0001 is below"):
            session.step(probes=[Probe(AT, 0.01, 1e-4)], repeat=4)
        assert session.step(frame=False).k == 1
