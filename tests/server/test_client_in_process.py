"""The Client against the real dispatcher in this process, through its transport seam.

No sockets: every byte the Client sends goes through ``Dispatcher.handle`` and back, so the
schema's two sides (``Request.to_wire``/``from_wire``, ``SceneInfo``/``Frame``'s
``to_reply_fields``/``from_reply``) meet here exactly as they do on the wire.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from membrane_client import Client, ServerError, UserError
from membrane_client.protocol import ErrorCode
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.scene import scene_from_dict
from membrane_server.served import ServedScene


def _rope(**changes: Any) -> ServedScene:
    data: dict[str, Any] = {
        "name": "rope",
        "model": "string-forced",
        "evaluator": "exact",
        "lattice": {"nx": 11},
        "dt": 0.01,
        "duration": 1.0,
        "policy": "error",
        "placement": {"origin": [0.0, 0.0, 1.0], "size": 2.0, "scale": 100.0, "axis": "z"},
    }
    data.update(changes)
    return ServedScene.load(scene_from_dict(data))


@pytest.fixture(scope="module")
def rope() -> ServedScene:
    return _rope()


def _client(*scenes: ServedScene) -> Client:
    return Client("in-process://test", transport=InProcessTransport(Dispatcher(list(scenes))))


def test_describe_reads_back_what_the_server_wrote(rope: ServedScene) -> None:
    with _client(rope) as client:
        info = client.describe()
    assert info.name == "rope" and info.shape == (11,) and info.steps == 101
    assert info.evaluator == "exact" and info.revision == rope.revision
    np.testing.assert_array_equal(info.points, rope.evaluator.points)
    np.testing.assert_array_equal(info.origin, [0.0, 0.0, 1.0])
    assert (info.size, info.scale, info.axis) == (2.0, 100.0, "z")
    assert info.model["problem"] == "string-forced"


def test_a_query_is_the_served_frame_bit_for_bit(rope: ServedScene) -> None:
    with _client(rope) as client:
        for t in (0.0, 0.25, 0.5, 1.0):
            frame = client.query(t, dtype="<f8")
            expected = rope.query(t, "<f8")
            assert frame.step == expected["step"] and frame.t == expected["t"]
            assert frame.requested_t == t and frame.domain == "inside"
            np.testing.assert_array_equal(frame.z.reshape(-1), rope.frame(rope.timeline.resolve(t)))
            positions = frame.positions()
            np.testing.assert_allclose(positions[:, 2], 1.0 + 100.0 * frame.z.reshape(-1))
            np.testing.assert_allclose(positions[:, 0], 2.0 * rope.evaluator.points[:, 0])


@pytest.mark.parametrize(
    ("t", "code"),
    [(float("nan"), ErrorCode.INVALID_TIME), (5.0, ErrorCode.OUT_OF_DOMAIN)],
)
def test_refusals_arrive_as_server_errors_with_their_code(
    rope: ServedScene, t: float, code: ErrorCode
) -> None:
    with _client(rope) as client, pytest.raises(ServerError) as refused:
        client.query(t)
    assert refused.value.code == code


def test_an_unknown_scene_and_a_second_scene(rope: ServedScene) -> None:
    other = _rope(name="short", lattice={"nx": 3})
    with _client(rope, other) as client:
        with pytest.raises(ServerError) as refused:
            client.query(0.1)  # two scenes, none named
        assert refused.value.code == ErrorCode.UNKNOWN_SCENE
        assert client.query(0.1, scene="short").z.shape == (3,)
        assert client.query(0.1, scene="rope").z.shape == (11,)
        assert sorted(client.hello().scenes) == ["rope", "short"]


def test_a_reloaded_scene_is_described_again(rope: ServedScene) -> None:
    transport = InProcessTransport(Dispatcher([rope]))
    with Client("in-process://test", transport=transport) as client:
        assert client.query(0.1).z.shape == (11,)
        transport.dispatcher = Dispatcher([_rope(lattice={"nx": 5})])  # as Server.reload swaps
        frame = client.query(0.1)
    assert frame.z.shape == (5,) and frame.info is not None and frame.info.n_points == 5
    assert frame.positions().shape == (5, 3)


def test_a_closed_client_refuses_and_bad_arguments_are_user_errors(rope: ServedScene) -> None:
    client = _client(rope)
    client.close()
    with pytest.raises(Exception, match="closed"):
        client.ping()
    with pytest.raises(UserError, match="timeout"):
        Client("in-process://test", timeout=0, transport=InProcessTransport(Dispatcher([rope])))
