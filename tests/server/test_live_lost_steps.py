"""Steps whose replies are lost on every retry, and frames in float64: the real dispatcher in
this process, the real Client and Session, a transport seam that loses what it is told to.

A Session whose step got no reply must not be left a step behind the server (the next step
would be refused as ``step_mismatch`` though the lost one was applied) nor a step ahead (the
lost one was never taken): ``StepLost`` says which, from the server's own count and token.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from membrane_client import Client, Load, StepLost, Timeout
from membrane_client.protocol import Request, decode, encode
from membrane_client.session import Session
from membrane_models.live import Load as EngineLoad
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.served import ServedScene

PRESS = Load((0.5, 0.5), 0.1, 0.05)


class LossyTransport(InProcessTransport):
    """The in-process seam, losing the next ``lose`` exchanges: ``after`` the server handled
    the request (its reply lost) or before it arrived (the request lost)."""

    def __init__(self, dispatcher: Dispatcher) -> None:
        super().__init__(dispatcher)
        self.lose, self.after = 0, True

    def round_trip(self, payload: bytes, stale: Callable[[bytes], bool] | None = None) -> bytes:
        if self.lose == 0:
            return super().round_trip(payload, stale)
        self.lose -= 1
        if self.after:
            super().round_trip(payload, stale)
        raise Timeout("no reply from in-process://lossy within 0.1 s (after 2 retries)")


@pytest.fixture(scope="module")
def scene() -> ServedScene:
    return ServedScene.load("membrane-live")


def _session(scene: ServedScene) -> tuple[Session, LossyTransport]:
    transport = LossyTransport(Dispatcher([scene]))
    client = Client("in-process://lossy", transport=transport)
    return client.session("membrane-live"), transport


def test_a_step_applied_but_unanswered_says_so_and_the_session_follows(
    scene: ServedScene,
) -> None:
    session, transport = _session(scene)
    session.step(loads=[PRESS])
    transport.lose = 1
    with pytest.raises(StepLost) as lost:
        session.step(loads=[PRESS])
    assert lost.value.applied is True and lost.value.k == 2 and session.k == 2
    assert "the server took it" in str(lost.value) and "next k = 2" in str(lost.value)
    assert session.step(loads=[PRESS]).k == 3  # in step again: no step_mismatch


def test_a_step_that_never_arrived_says_so_and_is_taken_next_time(scene: ServedScene) -> None:
    session, transport = _session(scene)
    transport.lose, transport.after = 1, False
    with pytest.raises(StepLost) as lost:
        session.step(loads=[PRESS])
    assert lost.value.applied is False and lost.value.k == 0 and session.k == 0
    assert session.step(loads=[PRESS]).k == 1


def test_when_the_read_is_lost_too_the_outcome_is_unknown_and_k_is_kept(
    scene: ServedScene,
) -> None:
    session, transport = _session(scene)
    transport.lose = 2  # the step's reply and the read's
    with pytest.raises(StepLost) as lost:
        session.step(loads=[PRESS])
    assert lost.value.applied is None and lost.value.k is None and session.k == 0
    assert "unknown" in str(lost.value)
    again = session.step(loads=[PRESS])  # k = 0 again, by this token: a re-send of the lost one
    assert again.k == 1 and session.step(loads=[PRESS]).k == 2  # answered once, from the store


def test_another_sessions_step_is_not_taken_for_ours(scene: ServedScene) -> None:
    """Two Session objects on one id (a bearer token without keys): A's step k = 0 is lost
    before it arrives; B takes k = 0; A learns its step was not taken."""
    dispatcher = Dispatcher([scene])
    a_transport = LossyTransport(dispatcher)
    a = Client("in-process://a", transport=a_transport).session("membrane-live")
    b = Session(Client("in-process://b", transport=InProcessTransport(dispatcher)), a.scene, a.id)
    a_transport.lose, a_transport.after = 1, False
    with pytest.raises(StepLost) as lost:
        a.step(loads=[PRESS])
    assert lost.value.applied is False and lost.value.k == 0  # the read shows k = 0
    b.step(loads=[PRESS])
    a_transport.lose = 1
    with pytest.raises(StepLost) as lost:
        a.step(loads=[PRESS])  # k = 0 again, lost after the server refused it
    assert lost.value.applied is False and a.k == 1


def test_a_step_and_a_read_can_ask_for_float64_frames(scene: ServedScene) -> None:
    session, _ = _session(scene)
    single = session.step(loads=[PRESS])
    double = session.step(loads=[PRESS], dtype="<f8")
    assert single.z is not None and single.z.dtype == np.float32
    assert double.z is not None and double.z.dtype == np.float64
    engine = scene.live
    assert engine is not None
    state = engine.start().state
    load = EngineLoad((0.5, 0.5), 0.1, 0.05)
    for _ in range(2):
        state = engine.step(state, [load]).state
    assert np.array_equal(double.z.ravel(), engine.frame(state))  # every digit of the engine's
    read = session.frame(dtype="<f8").z
    assert read is not None and np.array_equal(read, double.z)
    wire = decode(Request("step", 7, session.id, scene="membrane-live", k=2).to_wire())
    error = decode(Dispatcher([scene]).handle([encode({**wire, "dtype": "<f2"})]).reply)["error"]
    assert error["code"] == "bad_request" and "'dtype' must be one of" in error["message"]
