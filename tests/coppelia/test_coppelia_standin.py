"""The CoppeliaSim stand-in, driven by the real coppeliasim-zmqremoteapi-client (unmodified)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import cbor2
import pytest
import zmq

pytest.importorskip("coppeliasim_zmqremoteapi_client")
from coppeliasim_zmqremoteapi_client import RemoteAPIClient

from membrane_coppelia.batch_script import BATCH_FUNCTION, BATCH_SCRIPT
from membrane_coppelia.standin import RELEASES, SIM_CONSTANTS, CoppeliaStandin, FakeScene

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


def _wait_until_stopped(sim: Any) -> None:
    deadline = time.monotonic() + 5.0
    while sim.getSimulationState() != sim.simulation_stopped:
        assert time.monotonic() < deadline, "the simulation did not stop"
        time.sleep(0.005)


def test_stepping_handshake_advances_time_by_dt(standin: CoppeliaStandin) -> None:
    remote = _remote(standin.port)
    try:
        sim = remote.require("sim")
        assert sim.setStepping(True) == 0
        assert sim.setStepping(True) == 1
        sim.step()  # stopped: one wait, and time stays
        waits = standin.protocol.snapshot()[remote.uuid].waits
        assert waits == 1 and sim.getSimulationTime() == 0.0
        sim.startSimulation()
        assert sim.getSimulationState() == sim.simulation_advancing_firstafterstop
        time.sleep(0.05)  # held: a stepping client keeps the simulation at its pass
        assert sim.getSimulationTime() == 0.0
        for _ in range(5):
            sim.step()
        assert sim.getSimulationTime() == pytest.approx(0.05, abs=1e-15)
        assert sim.getSimulationState() == sim.simulation_advancing_running
        # Running, each step waits for its pass to end: one wait at least, and one more for each
        # _*executed*_ that arrives within the pass's 2 ms window (on a loaded machine the
        # client's round trip alone can take longer, and the pass ends after a single wait).
        assert standin.protocol.snapshot()[remote.uuid].waits - waits >= 5
        assert standin.scene.calls["sim.step"] == 6
        sim.stopSimulation()
        assert standin.stepping_levels() == {remote.uuid: 0}  # reset by the stop, at once
        _wait_until_stopped(sim)
        assert sim.getSimulationTime() == 0.0
    finally:
        remote.socket.close(linger=0)


def test_stop_takes_several_passes_and_restores_positions() -> None:
    scene = FakeScene(dt=0.01)
    ball = scene.create_primitive_shape(4, [0.05] * 3)
    scene.start_simulation()
    scene.set_position(ball, [0.0, 0.0, 3.0], -1)
    scene.end_pass()
    scene.stop_simulation()
    states = [scene.state]
    for _ in range(3):
        scene.end_pass()
        states.append(scene.state)
    assert states == [17, 21, 22, 0]  # running, about to stop, last before stop, stopped
    assert scene.positions_at_stop[ball] == (0.0, 0.0, 3.0)
    assert scene.world_position(ball) == (0.0, 0.0, 0.0) and scene.time == 0.0


def test_stop_over_the_wire_restores_positions(standin: CoppeliaStandin, sim: Any) -> None:
    ball = sim.createPrimitiveShape(sim.primitiveshape_spheroid, [0.05, 0.05, 0.05], 0)
    sim.startSimulation()
    sim.setObjectPosition(ball, [0.0, 0.0, 3.0], sim.handle_world)
    sim.stopSimulation()
    _wait_until_stopped(sim)
    assert sim.getObjectPosition(ball) == [0.0, 0.0, 0.0]
    assert standin.scene.positions_at_stop[ball] == (0.0, 0.0, 3.0)


def test_set_float_param_returns_0_while_running_and_clamps(sim: Any) -> None:
    step = sim.floatparam_simulation_time_step
    assert sim.setFloatParam(step, 0.02) == 1 and sim.getSimulationTimeStep() == 0.02
    assert sim.setFloatParam(step, 1e-6) == 1 and sim.getSimulationTimeStep() == 1e-4
    assert sim.setFloatParam(step, 20.0) == 1 and sim.getSimulationTimeStep() == 10.0
    sim.setFloatParam(step, 0.02)
    sim.startSimulation()
    assert sim.setFloatParam(step, 0.05) == 0  # no error, and nothing changed
    assert sim.getSimulationTimeStep() == 0.02


def test_properties_and_legacy_signals_are_separate_stores(standin: CoppeliaStandin) -> None:
    remote = _remote(standin.port)
    try:
        sim = remote.require("sim")
        sim.setFloatProperty(sim.handle_scene, "timeStep", 0.002)
        assert sim.getSimulationTimeStep() == 0.002
        sim.setFloatProperty(sim.handle_scene, "signal.force", 1.5)
        sim.setFloatSignal("force", 2.5)
        assert sim.getFloatProperty(sim.handle_scene, "signal.force") == 1.5
        assert sim.getFloatSignal("force") == 2.5
        assert sim.getFloatSignal("other") is None
        ball = sim.createPrimitiveShape(sim.primitiveshape_spheroid, [0.05, 0.05, 0.05], 0)
        sim.setBoolProperty(ball, "dynamic", False)
        sim.setBoolProperty(ball, "respondable", True)
        assert standin.scene.objects[ball].int_params == {3003: 1, 3004: 1}
        with pytest.raises(Exception, match="unknown property 'color'"):
            sim.setBoolProperty(ball, "color", True)
    finally:
        remote.socket.close(linger=0)


@pytest.mark.parametrize("version", ["4.6", "4.7", "4.8", "4.9"])
def test_each_version_offers_its_calls(version: str) -> None:
    with CoppeliaStandin(version=version) as standin:
        remote = _remote(standin.port)
        try:
            sim = remote.require("sim")
            assert sim.getInt32Param(sim.intparam_program_version) == RELEASES[version].number
            assert hasattr(sim, "createScript") is (version != "4.6")
            assert hasattr(sim, "addScript") is (version == "4.6")
            assert hasattr(sim, "setFloatProperty") is (version in ("4.8", "4.9"))
            assert hasattr(sim, "setFloatParam") and hasattr(sim, "setFloatSignal")
        finally:
            remote.socket.close(linger=0)


def test_46_scripts_are_not_scene_objects() -> None:
    with CoppeliaStandin(version="4.6") as standin:
        remote = _remote(standin.port)
        try:
            sim = remote.require("sim")
            holder = sim.createDummy(0.05)
            script = sim.addScript(sim.scripttype_customizationscript)
            sim.setScriptStringParam(script, sim.scriptstringparam_text, BATCH_SCRIPT)
            sim.associateScriptWithObject(script, holder)
            assert sim.initScript(script) is None
            assert sim.callScriptFunction(BATCH_FUNCTION, script, [], [], holder) == 0
            with pytest.raises(Exception, match="object does not exist"):
                sim.setObjectAlias(script, "mover")
            sim.removeObjects([holder])  # its script goes with it
            assert standin.scene.objects == {}
        finally:
            remote.socket.close(linger=0)


def test_init_script_can_take_effect_passes_later() -> None:
    with CoppeliaStandin(init_delay_passes=5) as standin:
        remote = _remote(standin.port)
        try:
            sim = remote.require("sim")
            script = sim.createScript(sim.scripttype_customization, BATCH_SCRIPT, 0, "lua")
            assert sim.initScript(script) is None
            with pytest.raises(Exception, match="not initialized"):
                sim.callScriptFunction(BATCH_FUNCTION, script, [], [])
            deadline = time.monotonic() + 5.0
            while not standin.scene.objects[script].script_initialized:
                assert time.monotonic() < deadline
                time.sleep(0.01)
            assert sim.callScriptFunction(BATCH_FUNCTION, script, [], []) == 0
        finally:
            remote.socket.close(linger=0)


def test_objects_by_path_and_animated(standin: CoppeliaStandin, sim: Any) -> None:
    robot = sim.createDummy(0.05)
    sim.setObjectAlias(robot, "robot")
    tip = sim.createDummy(0.01)
    sim.setObjectAlias(tip, "tip")
    sim.setObjectParent(tip, robot, True)
    assert sim.getObject("/robot/tip") == tip and sim.getObject("/robot") == robot
    with pytest.raises(Exception, match="object does not exist"):
        sim.getObject("/tip")  # not at the root
    assert sim.getObject("/nothing", {"noError": True}) == -1
    standin.scene.animate(tip, lambda t: (t, 0.0, 1.0))
    sim.setStepping(True)
    sim.startSimulation()
    for _ in range(3):
        sim.step()
    assert sim.getObjectPosition(tip, sim.handle_world) == [pytest.approx(0.03), 0.0, 1.0]


def test_a_vanished_stepping_client_holds_until_its_timeout(standin: CoppeliaStandin) -> None:
    stepper = RemoteAPIClient("127.0.0.1", standin.port)
    stepper.timeout = 0.5  # sent with its first request
    watcher = _remote(standin.port)
    try:
        sim = stepper.require("sim")
        sim.setStepping(True)
        sim.startSimulation()
        sim.step()
        stepper.socket.close(linger=0)  # gone without a word
        time.sleep(0.2)
        assert standin.protocol.held()
        frozen = watcher.require("sim").getSimulationTime()
        start = time.monotonic()
        while standin.protocol.held():
            assert time.monotonic() - start < 3.0, "still held"
            time.sleep(0.01)
        assert standin.protocol.forgotten == [stepper.uuid]
        assert watcher.require("sim").getSimulationTime() >= frozen
    finally:
        watcher.socket.close(linger=0)


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
    other_version = {"func": "zmqRemoteApi.require", "args": ["sim"], "uuid": "u", "ver": 1}
    # The add-on does not check 'ver': the call is served.
    assert _raw_round_trip(standin.port, cbor2.dumps(other_version)) == {"ret": []}


def test_a_standin_that_stops_answering_times_the_client_out() -> None:
    with CoppeliaStandin(answer_limit=3) as standin:
        remote = _remote(standin.port, timeout_ms=200)
        sim = remote.require("sim")  # two replies
        assert sim.getSimulationTime() == 0.0  # the third
        with pytest.raises(zmq.Again):
            sim.getSimulationTime()
        remote.socket.close(linger=0)


@pytest.mark.slow
def test_runs_as_a_module_and_stops_on_sigterm() -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "membrane_coppelia.standin", "--port", "0", "--dt", "0.01"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert line.startswith("coppelia stand-in listening on tcp://127.0.0.1:"), line
        assert line.rstrip().endswith("(CoppeliaSim 4.9)")
        port = int(line.split()[4].rsplit(":", 1)[1])
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


@pytest.mark.slow
def test_bad_arguments_exit_2() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "membrane_coppelia.standin", "--dt", "-1"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    assert "--dt must be > 0" in result.stderr
