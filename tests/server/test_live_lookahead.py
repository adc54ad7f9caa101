"""A step's look-ahead: each probe's ``next_free`` is the next step's free displacement, so
max(0, (next_free + d) / compliance) is the next step's force at any depth d (what the haptic
loop renders from), and ``static_compliance`` is the tissue's settled compliance there."""

from __future__ import annotations

import math
from typing import Any

import pytest

from membrane_client import Client, ServerError
from membrane_client.protocol import Request, RequestError, encode
from membrane_client.session import Load, Probe, Tool

AT, RADIUS = (0.5, 0.5), 0.05


def test_the_look_ahead_gives_the_next_steps_force_at_any_depth(start_server: Any) -> None:
    server = start_server(["membrane-live"])
    with Client(server.address) as client, client.session("membrane-live") as session:
        frame = session.step([Load(AT, -0.02, RADIUS)], [Probe(AT, 0.0, RADIUS)], lookahead=True)
        for depth in (1e-4, 4e-4, 2e-4, 8e-4, 0.0, 6e-4):
            ahead = frame.probes[0]
            predicted = max(0.0, (ahead.next_free + depth) / ahead.compliance)
            lagged = max(0.0, (ahead.displacement + ahead.compliance * ahead.force + depth))
            frame = session.step(
                [Load(AT, -0.02, RADIUS)], [Probe(AT, depth, RADIUS)], lookahead=True
            )
            assert frame.probes[0].force == pytest.approx(predicted, rel=1e-12, abs=1e-15)
            if predicted > 0:  # this step's own free displacement would not do
                assert abs(lagged / ahead.compliance - predicted) > 1e-3 * predicted
        plain = session.step(probes=[Probe(AT, 0.0, RADIUS)]).probes[0]
        assert math.isnan(plain.next_free)  # only when asked for
        # the static compliance is the settled one: membrane-live's 1 / 67.70 at the centre
        assert 1 / plain.static_compliance == pytest.approx(67.70, rel=1e-3)


def test_a_look_ahead_beside_tools_or_not_a_boolean_is_refused(start_server: Any) -> None:
    server = start_server(["membrane-live"])
    refused = pytest.raises(ServerError, match="'lookahead' is for steps of loads and probes")
    with Client(server.address) as client, client.session("membrane-live") as session, refused:
        session.step(tools=[Tool("sphere", AT, 1e-4, 0.1)], lookahead=True)
    raw = {"v": 1, "id": 3, "op": "step", "session": "s", "k": 0, "lookahead": 1}
    with pytest.raises(RequestError, match="'lookahead' must be true or false, got 1"):
        Request.from_wire(encode(raw))
