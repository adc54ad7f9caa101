"""The thin client against a real server in this process: frames and geometry, server errors.

Split from tests/client/test_client.py, which needs no server; also the server's own imports
(no torch, even once a scene is loaded).
"""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from membrane_client import Client, Frame, MembraneError, SceneInfo, ServerError
from membrane_server.server import Server

# -- frames and geometry ----------------------------------------------------------------------


def test_query_returns_a_frame_shaped_like_the_lattice(membrane_server: Server) -> None:
    with Client(membrane_server.address, timeout=5.0) as client:
        frame = client.query(0.5)
    assert isinstance(frame, Frame)
    assert (frame.scene, frame.step, frame.t, frame.requested_t) == ("membrane", 50, 0.5, 0.5)
    assert frame.z.shape == (20, 20)
    assert frame.z.dtype == np.float32
    assert not frame.z.flags.writeable


def test_positions_are_rest_plus_scaled_displacement(membrane_server: Server) -> None:
    with Client(membrane_server.address, timeout=5.0) as client:
        info = client.describe()
        frame = client.query(0.5)
    assert isinstance(info, SceneInfo)
    rest = info.rest_positions()
    assert rest.shape == (400, 3)
    np.testing.assert_allclose(rest[:, :2], info.points)  # size 1, origin (0, 0, 1)
    np.testing.assert_allclose(rest[:, 2], 1.0)
    positions = frame.positions()
    np.testing.assert_allclose(positions[:, :2], rest[:, :2])
    z = frame.z.reshape(-1).astype(np.float64)
    np.testing.assert_allclose(positions[:, 2], 1.0 + 100.0 * z)
    assert np.abs(positions[:, 2] - 1.0).max() > 0.01  # visibly displaced at t = 0.5


def test_placement_axis_size_and_origin(start_server: Any, make_scene: Any) -> None:
    placement = {"origin": [1.0, 2.0, 3.0], "size": 2.0, "scale": -10.0, "axis": "y"}
    scene = make_scene(
        "membrane-forced", "exact", name="s", lattice={"nx": 3, "ny": 2}, placement=placement
    )
    server = start_server([scene])
    with Client(server.address, timeout=5.0) as client:
        info = client.describe()
        frame = client.query(0.5)
    assert (info.axis, info.size, info.scale) == ("y", 2.0, -10.0)
    rest = info.rest_positions()
    # Axis y: lattice x runs along world x, lattice y along world z.
    np.testing.assert_allclose(rest[:, 0], 1.0 + 2.0 * info.points[:, 0])
    np.testing.assert_allclose(rest[:, 1], 2.0)
    np.testing.assert_allclose(rest[:, 2], 3.0 + 2.0 * info.points[:, 1])
    moved = frame.positions()
    np.testing.assert_allclose(moved[:, 1], 2.0 - 10.0 * frame.z.reshape(-1).astype(np.float64))
    np.testing.assert_array_equal(moved[:, [0, 2]], rest[:, [0, 2]])


def test_rope_geometry(start_server: Any) -> None:
    server = start_server(["rope"])
    with Client(server.address, timeout=5.0) as client:
        info = client.describe()
    assert info.shape == (100,)
    rest = info.rest_positions()
    np.testing.assert_allclose(rest[:, 0], np.linspace(0.0, 1.0, 100))
    np.testing.assert_allclose(rest[:, 1:], [[0.0, 1.0]] * 100)
    np.testing.assert_allclose(info.times()[[0, -1]], [0.0, 1.0])


def test_float64_query(membrane_server: Server) -> None:
    with Client(membrane_server.address, timeout=5.0) as client:
        single = client.query(0.5)
        double = client.query(0.5, dtype="<f8")
    assert double.z.dtype == np.float64
    np.testing.assert_array_equal(double.z.astype(np.float32), single.z)


def test_describe_is_cached_per_scene(membrane_server: Server) -> None:
    with Client(membrane_server.address, timeout=5.0) as client:
        first = client.describe()
        assert client.describe() is first
        assert client.describe(refresh=True) is not first


# -- errors -----------------------------------------------------------------------------------


def test_server_error_carries_the_code(membrane_server: Server) -> None:
    with Client(membrane_server.address, timeout=5.0, scene="nope") as client:
        with pytest.raises(ServerError) as caught:
            client.describe()
        assert caught.value.code == "unknown_scene"
        assert isinstance(caught.value, MembraneError)
        assert client.ping() > 0  # the client is still usable


# -- the server's imports ---------------------------------------------------------------------


@pytest.mark.slow
def test_server_imports_no_torch() -> None:
    code = (
        "import sys, membrane_server.server, membrane_server.dispatch\n"
        "from membrane_server.served import ServedScene\n"
        "ServedScene.load('rope')\n"
        "print('torch' in sys.modules)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
