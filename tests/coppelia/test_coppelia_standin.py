"""The CoppeliaSim stand-in, driven by the real coppeliasim-zmqremoteapi-client (unmodified)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import cbor2
import pytest
import zmq

pytest.importorskip("coppeliasim_zmqremoteapi_client")
from coppeliasim_zmqremoteapi_client import RemoteAPIClient

from membrane_coppelia.coppelia_lua import BATCH_FUNCTION, BATCH_SCRIPT
from membrane_coppelia.coppelia_standin import SIM_CONSTANTS, CoppeliaStandin

TIMEOUT_MS = 2000


def _remote(port: int, timeout_ms: int = TIMEOUT_MS) -> RemoteAPIClient:
    remote = RemoteAPIClient("127.0.0.1", port)
    remote.socket.setsockopt(zmq.RCVTIMEO, timeout_ms)
    remote.socket.setsockopt(zmq.SNDTIMEO, timeout_ms)
    remote.socket.setsockopt(zmq.LINGER, 0)
    return remote


@pytest.fixture
def standin() -> Iterator[CoppeliaStandin]:
    with CoppeliaStandin(dt=0.01) as server:
        yield server


@pytest.fixture
def sim(standin: CoppeliaStandin) -> Iterator[Any]:
    remote = _remote(standin.port)
    yield remote.require("sim")
    remote.socket.close(linger=0)


def test_require_returns_functions_and_constants(standin: CoppeliaStandin, sim: Any) -> None:
    assert sim.primitiveshape_spheroid == 4
    assert sim.handle_world == -1
    assert sim.shapeintparam_static == 3003 and sim.shapeintparam_respondable == 3004
    assert sim.simulation_stopped == SIM_CONSTANTS["simulation_stopped"]
    assert callable(sim.createPrimitiveShape) and callable(sim.step)
    assert standin.scene.calls["zmqRemoteApi.require"] == 1
    assert standin.scene.calls["zmqRemoteApi.info"] == 1


def test_objects_parents_and_positions(standin: CoppeliaStandin, sim: Any) -> None:
    parent = sim.createDummy(0.05)
    ball = sim.createPrimitiveShape(sim.primitiveshape_spheroid, [0.05, 0.05, 0.05], 0)
    sim.setObjectParent(ball, parent, True)
    sim.setObjectPosition(parent, [1.0, 0.0, 0.0], sim.handle_world)
    assert sim.getObjectPosition(ball, sim.handle_world) == [1.0, 0.0, 0.0]  # moved with parent
    sim.setObjectPosition(ball, [0.0, 2.0, 0.0], parent)
    assert sim.getObjectPosition(ball) == [1.0, 2.0, 0.0]
    sim.setObjectPosition(ball, sim.handle_world, [0.5, 0.5, 0.5])  # the old argument order
    assert sim.getObjectPosition(ball, parent) == [-0.5, 0.5, 0.5]
    sim.setObjectInt32Param(ball, sim.shapeintparam_static, 1)
    sim.setShapeColor(ball, None, sim.colorcomponent_ambient_diffuse, [0.1, 0.2, 0.3])
    sim.setObjectAlias(ball, "node0")
    shape = standin.scene.objects[ball]
    assert (shape.kind, shape.primitive, shape.size) == ("shape", 4, (0.05, 0.05, 0.05))
    assert shape.int_params == {3003: 1}
    assert shape.colors == {0: (0.1, 0.2, 0.3)}
    assert sim.getObjectAlias(ball) == "node0"
    assert sim.getObjectsInTree(parent) == [parent, ball]
    sim.removeObjects([ball, parent])
    assert standin.scene.objects == {}


def test_stepping_handshake_advances_time_by_dt(standin: CoppeliaStandin, sim: Any) -> None:
    assert sim.setStepping(True) == 0
    assert sim.setStepping(True) == 1
    sim.step()  # stopped: the handshake completes, time stays
    assert sim.getSimulationTime() == 0.0
    sim.startSimulation()
    assert sim.getSimulationState() == sim.simulation_advancing_running
    for _ in range(5):
        sim.step()
    assert sim.getSimulationTime() == pytest.approx(0.05, abs=1e-15)
    assert standin.scene.calls["sim.step"] == 6
    sim.stopSimulation()
    assert standin.scene.stepping_level == 0  # reset on stop, as the real server does
    assert sim.getSimulationTime() == 0.0


def test_stop_restores_positions_and_records_them(standin: CoppeliaStandin, sim: Any) -> None:
    ball = sim.createPrimitiveShape(sim.primitiveshape_spheroid, [0.05, 0.05, 0.05], 0)
    sim.startSimulation()
    sim.setObjectPosition(ball, [0.0, 0.0, 3.0], sim.handle_world)
    sim.stopSimulation()
    assert sim.getObjectPosition(ball) == [0.0, 0.0, 0.0]
    assert standin.scene.positions_at_stop[ball] == (0.0, 0.0, 3.0)


def test_time_step_changes_only_while_stopped(standin: CoppeliaStandin, sim: Any) -> None:
    sim.setFloatParam(sim.floatparam_simulation_time_step, 0.02)
    assert sim.getSimulationTimeStep() == 0.02
    sim.startSimulation()
    with pytest.raises(Exception, match="cannot change while the simulation runs"):
        sim.setFloatParam(sim.floatparam_simulation_time_step, 0.05)


def test_batch_script_function_moves_objects(standin: CoppeliaStandin, sim: Any) -> None:
    frame = sim.createDummy(0.05)
    sim.setObjectPosition(frame, [0.0, 0.0, 1.0], sim.handle_world)
    balls = [sim.createPrimitiveShape(4, [0.05, 0.05, 0.05], 0) for _ in range(3)]
    script = sim.createScript(sim.scripttype_customization, BATCH_SCRIPT, 0, "lua")
    with pytest.raises(Exception, match="not initialized"):
        sim.callScriptFunction(BATCH_FUNCTION, script, [], [])
    sim.initScript(script)
    flat = [float(v) for v in range(9)]
    assert sim.callScriptFunction(BATCH_FUNCTION, script, balls, flat, frame) == 3
    assert [sim.getObjectPosition(b) for b in balls] == [
        [0.0, 1.0, 3.0],
        [3.0, 4.0, 6.0],
        [6.0, 7.0, 9.0],
    ]
    assert sim.callScriptFunction(BATCH_FUNCTION, script, balls[:1], [1.0, 1.0, 1.0]) == 1
    assert sim.getObjectPosition(balls[0]) == [1.0, 1.0, 1.0]  # default frame: the world
    with pytest.raises(Exception, match="need 6 coordinates, got 5"):
        sim.callScriptFunction(BATCH_FUNCTION, script, balls[:2], [1.0] * 5)


def test_script_function_must_be_defined_by_the_script_text(sim: Any) -> None:
    script = sim.createScript(sim.scripttype_customization, "function other() end", 0, "lua")
    sim.initScript(script)
    with pytest.raises(Exception, match="does not exist"):
        sim.callScriptFunction(BATCH_FUNCTION, script, [], [])


def test_errors_are_replies_and_the_server_keeps_serving(sim: Any) -> None:
    with pytest.raises(Exception, match="object does not exist"):
        sim.getObjectPosition(12345)
    with pytest.raises(Exception, match="sizes"):
        sim.createPrimitiveShape(sim.primitiveshape_spheroid, [0.05, 0.05], 0)
    with pytest.raises(Exception, match="invalid arguments"):
        sim.getSimulationTime(1, 2, 3)
    assert sim.getSimulationTime() == 0.0


def test_unknown_function_is_an_error(standin: CoppeliaStandin) -> None:
    remote = _remote(standin.port)
    try:
        remote.require("sim")
        with pytest.raises(Exception, match=r"No such function: sim\.noSuchThing"):
            remote.call("sim.noSuchThing", [])
        with pytest.raises(Exception, match="module not found"):
            remote.require("simIK")
    finally:
        remote.socket.close(linger=0)


def _raw_round_trip(port: int, payload: bytes) -> Any:
    socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.REQ)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, TIMEOUT_MS)
    socket.connect(f"tcp://127.0.0.1:{port}")
    try:
        socket.send(payload)
        return cbor2.loads(socket.recv())
    finally:
        socket.close(linger=0)


def test_malformed_requests_get_error_replies(standin: CoppeliaStandin) -> None:
    old_client = _raw_round_trip(standin.port, cbor2.dumps({"func": "sim.getObject", "args": []}))
    assert old_client["success"] is False and "version" in old_client["error"]
    assert "err" in _raw_round_trip(standin.port, b"\xff\x00 not cbor")
    bad_version = {"func": "sim.getSimulationTime", "args": [], "uuid": "u", "ver": 1}
    assert (
        "unsupported protocol version"
        in _raw_round_trip(standin.port, cbor2.dumps(bad_version))["err"]
    )


def test_a_standin_that_stops_answering_times_the_client_out() -> None:
    with CoppeliaStandin(answer_limit=3) as standin:
        remote = _remote(standin.port, timeout_ms=200)
        sim = remote.require("sim")  # two replies
        assert sim.getSimulationTime() == 0.0  # the third
        with pytest.raises(zmq.Again):
            sim.getSimulationTime()
        remote.socket.close(linger=0)


def test_runs_as_a_module_and_stops_on_sigterm() -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "membrane_coppelia.coppelia_standin", "--port", "0", "--dt", "0.01"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert line.startswith("coppelia stand-in listening on tcp://127.0.0.1:"), line
        port = int(line.rsplit(":", 1)[1])
        remote = _remote(port)
        sim = remote.require("sim")
        assert sim.getSimulationTimeStep() == 0.01
        remote.socket.close(linger=0)
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=10) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def test_bad_arguments_exit_2() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "membrane_coppelia.coppelia_standin", "--dt", "-1"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    assert "--dt must be > 0" in result.stderr
