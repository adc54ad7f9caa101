"""The CoppeliaSim adapter against the stand-in (real remote API client) and a real server."""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from membrane_cli.dispatcher import main as membrane_main
from membrane_client import Client, SceneInfo
from membrane_coppelia.coppelia import (
    BATCHED,
    PER_SPHERE,
    LatticeStyle,
    SimulatorLink,
    SimulatorTimeout,
    SphereLattice,
    connect_simulator,
)
from membrane_coppelia.coppelia_compat import SimCalls, SimVersion, TimeStepRefused
from membrane_coppelia.coppelia_lua import BATCH_FUNCTION
from membrane_coppelia.coppelia_standin import CoppeliaStandin, FakeScene

REPO = Path(__file__).resolve().parents[2]
SIM_TIMEOUT = 2.0


# -- fixtures -------------------------------------------------------------------------------


@pytest.fixture
def standin() -> Iterator[CoppeliaStandin]:
    with CoppeliaStandin() as server:  # dt 0.05, CoppeliaSim's default: the adapter sets it
        yield server


@pytest.fixture
def link(standin: CoppeliaStandin) -> Iterator[SimulatorLink]:
    connection = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT)
    yield connection
    connection.close()


@pytest.fixture
def membrane_client(membrane_server: Any) -> Iterator[Client]:
    with Client(membrane_server.address, timeout=5.0) as client:
        yield client


@pytest.fixture
def short_server(start_server: Callable[..., Any], make_scene: Callable[..., Any]) -> Any:
    """A 10-point string scene, 0.05 s long, policy error; and the same with policy hold."""
    fields = {"lattice": {"nx": 10}, "duration": 0.05}
    return start_server(
        [
            make_scene("string-forced", "exact", name="strict", policy="error", **fields),
            make_scene("string-forced", "exact", name="lenient", policy="hold", **fields),
        ]
    )


def _lattice(link: SimulatorLink, client: Client, **kwargs: Any) -> SphereLattice:
    return SphereLattice(link.sim, client, address=link.address, timeout=link.timeout, **kwargs)


def _expected_world(info: SceneInfo, z: np.ndarray) -> np.ndarray:
    """Rest position plus scale * z along the axis, from describe's fields (not the client's)."""
    axis = "xyz".index(info.axis)
    lateral = [i for i in range(3) if i != axis]
    expected = np.tile(info.origin, (info.n_points, 1))
    for column in range(info.points.shape[1]):
        expected[:, lateral[column]] += info.size * info.points[:, column]
    expected[:, axis] += info.scale * z.reshape(-1).astype(np.float64)
    return expected


def _positions_at_stop(scene: FakeScene, handles: list[int]) -> np.ndarray:
    return np.array([scene.positions_at_stop[h] for h in handles])


# -- building the lattice -------------------------------------------------------------------


def test_build_places_the_described_lattice_under_one_parent(
    standin: CoppeliaStandin, link: SimulatorLink, membrane_client: Client
) -> None:
    style = LatticeStyle(sphere_size=0.04, color=(0.1, 0.2, 0.3), name="skin")
    lattice = _lattice(link, membrane_client, style=style)
    lattice.build()
    scene, info = standin.scene, membrane_client.describe()
    (parent,) = scene.of_kind("dummy")
    shapes = scene.of_kind("shape")
    assert parent.alias == "skin" and parent.handle == lattice.parent
    assert len(shapes) == info.n_points == 400
    assert [s.handle for s in shapes] == lattice.handles
    for index, shape in enumerate(shapes):
        assert shape.parent == parent.handle and shape.alias == f"node{index}"
        assert (shape.primitive, shape.size) == (4, (0.04, 0.04, 0.04))
        assert shape.int_params == {3003: 1, 3004: 1}  # static, respondable
        assert shape.colors == {0: (0.1, 0.2, 0.3)}
    rest = np.array([scene.world_position(h) for h in lattice.handles])
    np.testing.assert_allclose(rest, _expected_world(info, np.zeros(info.n_points)), atol=1e-12)
    (script,) = scene.of_kind("script")
    assert lattice.path == BATCHED and script.parent == parent.handle
    assert script.script_initialized and f"function {BATCH_FUNCTION}(" in script.script_text
    lattice.remove()
    assert scene.objects == {}


# -- running --------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("batched", [True, False], ids=[BATCHED, PER_SPHERE])
def test_run_moves_every_sphere_to_the_served_frame(
    standin: CoppeliaStandin, link: SimulatorLink, membrane_client: Client, batched: bool
) -> None:
    scene, info = standin.scene, membrane_client.describe()
    with _lattice(link, membrane_client, batched=batched) as lattice:
        lattice.build()
        before = scene.calls.copy()
        result = lattice.run(max_steps=30)
        during = scene.calls - before
        handles = list(lattice.handles)
    assert scene.objects == {}  # removed on exit
    assert (result.steps, result.reason, result.sim_dt) == (30, "max_steps", info.dt)
    assert result.first_t == 0.0 and result.last_t == pytest.approx(29 * info.dt, abs=1e-12)
    assert result.path == (BATCHED if batched else PER_SPHERE)
    assert during["sim.step"] == 30 and during["sim.getSimulationTime"] == 30
    if batched:
        assert during["sim.callScriptFunction"] == 30 and during["sim.setObjectPosition"] == 0
    else:
        assert during["sim.setObjectPosition"] == 30 * 400
    served = membrane_client.query(result.last_t)
    assert np.abs(served.z).max() > 1e-5  # the membrane moves by then: the check has teeth
    expected = _expected_world(info, served.z)
    np.testing.assert_allclose(_positions_at_stop(scene, handles), expected, rtol=0, atol=1e-6)
    assert result.last_positions is not None
    np.testing.assert_allclose(result.last_positions, expected, rtol=0, atol=1e-6)
    assert not scene.running and not any(standin.stepping_levels().values())
    timings = result.timings
    assert len(timings.read) == len(timings.query) == len(timings.move) == 30
    assert set(timings.percentiles()) == {"read", "query", "move", "step", "total"}


def test_changing_the_simulators_time_step_is_logged_once(
    standin: CoppeliaStandin,
    link: SimulatorLink,
    membrane_client: Client,
    caplog: pytest.LogCaptureFixture,
) -> None:
    dt = membrane_client.describe().dt
    assert standin.scene.dt != dt  # the stand-in starts at CoppeliaSim's default, 0.05 s
    with caplog.at_level(logging.WARNING), _lattice(link, membrane_client) as lattice:
        lattice.run(max_steps=1)
        lattice.run(max_steps=1)  # already at the scene's dt: nothing more to say
    changes = [r.getMessage() for r in caplog.records if "time step" in r.getMessage()]
    assert changes == [
        f"changed the simulator's time step from 0.05 s to {dt:g} s (the scene's dt); "
        "it stays so after the run"
    ]


def test_without_script_functions_it_falls_back_to_per_sphere(
    membrane_client: Client, caplog: pytest.LogCaptureFixture
) -> None:
    with CoppeliaStandin(scripts=False) as old:
        connection = connect_simulator("127.0.0.1", old.port, SIM_TIMEOUT)
        try:
            with (
                caplog.at_level(logging.WARNING),
                _lattice(connection, membrane_client) as lattice,
            ):
                lattice.build()
                result = lattice.run(max_steps=2)
        finally:
            connection.close()
        assert result.path == PER_SPHERE and result.steps == 2
        assert "CoppeliaSim 4.9.0 has neither sim.createScript (4.7+) nor" in caplog.text
        assert old.scene.objects == {}


def test_keep_leaves_the_lattice_in_the_scene(
    standin: CoppeliaStandin, link: SimulatorLink, membrane_client: Client
) -> None:
    with _lattice(link, membrane_client, keep=True) as lattice:
        lattice.run(max_steps=1)
    assert len(standin.scene.of_kind("shape")) == 400
    assert not standin.scene.running


def test_default_run_ends_with_the_scene(
    standin: CoppeliaStandin, link: SimulatorLink, short_server: Any
) -> None:
    with (
        Client(short_server.address, timeout=5.0, scene="strict") as client,
        _lattice(link, client) as lattice,
    ):
        result = lattice.run()
    assert (result.reason, result.steps) == ("completed", 6)
    assert result.last_t == pytest.approx(0.05, abs=1e-12)


def test_out_of_domain_under_policy_error_ends_the_run_cleanly(
    standin: CoppeliaStandin, link: SimulatorLink, short_server: Any
) -> None:
    with (
        Client(short_server.address, timeout=5.0, scene="strict") as client,
        _lattice(link, client) as lattice,
    ):
        result = lattice.run(duration=0.2)
    assert result.reason == "out_of_domain" and result.steps == 6
    assert "stopped at t = 0.06 s" in result.message
    assert not standin.scene.running and standin.scene.objects == {}


def test_policy_hold_runs_past_the_end(
    standin: CoppeliaStandin, link: SimulatorLink, short_server: Any
) -> None:
    with (
        Client(short_server.address, timeout=5.0, scene="lenient") as client,
        _lattice(link, client) as lattice,
    ):
        result = lattice.run(duration=0.1)
    assert (result.reason, result.steps) == ("completed", 11)


def test_a_simulator_that_stops_answering_raises_a_clear_timeout(
    membrane_client: Client,
) -> None:
    with CoppeliaStandin(answer_limit=500) as hung:  # dies while the lattice is being built
        connection = connect_simulator("127.0.0.1", hung.port, timeout=0.3)
        try:
            with (
                pytest.raises(SimulatorTimeout, match=r"did not answer within 0.3 s"),
                _lattice(connection, membrane_client) as lattice,
            ):
                lattice.run()
        finally:
            connection.close()
        assert hung.replies == 500


def test_nothing_listening_times_out() -> None:
    with CoppeliaStandin() as probe:  # a free port: bind one, then let it go
        port = probe.port
    with pytest.raises(SimulatorTimeout, match=rf"tcp://127.0.0.1:{port} did not answer"):
        connect_simulator("127.0.0.1", port, timeout=0.2)


# -- CoppeliaSim 4.6 to 4.9 ----------------------------------------------------------------


@pytest.mark.parametrize("version", ["4.6", "4.7", "4.8", "4.9"])
def test_each_version_runs_batched_with_the_calls_it_has(
    membrane_client: Client, version: str, caplog: pytest.LogCaptureFixture
) -> None:
    info = membrane_client.describe()
    with CoppeliaStandin(version=version) as standin:
        connection = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT)
        try:
            with caplog.at_level(logging.WARNING), _lattice(connection, membrane_client) as lattice:
                lattice.build()
                handles = list(lattice.handles)
                shapes = [standin.scene.objects[h] for h in handles]
                assert all(
                    s.int_params == {3003: 1, 3004: 1} for s in shapes
                )  # static, respondable
                result = lattice.run(max_steps=3)
        finally:
            connection.close()
        scene, calls = standin.scene, standin.scene.calls
    assert (result.path, result.steps, result.sim_dt) == (BATCHED, 3, info.dt)
    assert "batched moves unavailable" not in caplog.text
    served = membrane_client.query(result.last_t)
    expected = _expected_world(info, served.z)
    np.testing.assert_allclose(_positions_at_stop(scene, handles), expected, rtol=0, atol=1e-6)
    assert scene.objects == {} and not scene.running
    properties = version in ("4.8", "4.9")
    assert (calls["sim.setBoolProperty"] > 0) is properties
    assert (calls["sim.setObjectInt32Param"] > 0) is not properties
    assert (calls["sim.setFloatProperty"], calls["sim.setFloatParam"]) == (
        (1, 0) if properties else (0, 1)
    )
    if version == "4.6":  # scripts are no scene objects: attached, then removed as scripts
        assert calls["sim.addScript"] == calls["sim.associateScriptWithObject"] == 1
        assert calls["sim.removeScript"] == 1 and "sim.createScript" not in calls
    else:
        assert calls["sim.createScript"] == 1 and "sim.addScript" not in calls


def test_an_asynchronous_init_script_is_waited_for(membrane_client: Client) -> None:
    # The development line after 4.10 returns from sim.initScript before the script runs.
    with CoppeliaStandin(init_delay_passes=5) as standin:
        connection = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT)
        try:
            with _lattice(connection, membrane_client) as lattice:
                lattice.build()
                assert lattice.path == BATCHED
        finally:
            connection.close()
        assert standin.scene.calls["sim.callScriptFunction"] > 1  # it had to ask again


class _StubSim:
    """A sim object whose time step call does nothing (as setFloatParam while running)."""

    floatparam_simulation_time_step = 1

    def __init__(self, returned: int = 0) -> None:
        self.dt, self.returned = 0.05, returned

    def setFloatParam(self, param: int, value: float) -> int:
        return self.returned

    def getSimulationTimeStep(self) -> float:
        return self.dt


def test_a_time_step_that_did_not_take_is_an_error() -> None:
    calls = SimCalls(_StubSim(), SimVersion(40700))
    assert not calls.properties and calls.scripts is None
    with pytest.raises(TimeStepRefused, match=r"CoppeliaSim 4.7.0 kept its time step at 0.05 s "):
        calls.set_time_step(0.001)
    with pytest.raises(TimeStepRefused, match=r"must be in \[0.0001, 10\] s .* dt is 5e-05 s"):
        calls.set_time_step(5e-5)


def test_versions_read_as_people_write_them() -> None:
    assert str(SimVersion(40902)) == "4.9.2" and SimVersion(41000).major_minor == (4, 10)


# -- the command line -----------------------------------------------------------------------


def test_cli_runs_half_a_second(
    standin: CoppeliaStandin, membrane_server: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["coppelia", "--connect", membrane_server.address, "--sim-port", str(standin.port)]
    assert membrane_main([*argv, "--duration", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "scene membrane: 400 spheres moved batched: 51 steps, t = 0 .. 0.5 s" in out
    assert "per step p50/p99: read " in out and " step " in out
    assert standin.scene.calls["sim.step"] == 51 and standin.scene.objects == {}


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--duration", "-1"], "--duration: must be >= 0"),
        (["--sim-port", "70000"], "--sim-port: must be in 1..65535"),
        (["--color", "1,2"], "--color: expected 3 values"),
        (["--sim-timeout", "0"], "--sim-timeout: must be a positive number"),
        (["--scene", "nope"], "unknown_scene"),
    ],
)
def test_cli_bad_input_exits_2(
    standin: CoppeliaStandin,
    membrane_server: Any,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    argv = ["coppelia", "--connect", membrane_server.address, "--sim-port", str(standin.port)]
    assert _exit_code([*argv, *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def _exit_code(argv: list[str]) -> int:
    """`membrane` in-process: argparse errors exit (SystemExit), handlers return their code."""
    try:
        return membrane_main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


@pytest.mark.slow
def test_cli_exits_1_without_hanging_when_coppeliasim_stops_answering(
    membrane_server: Any,
) -> None:
    with CoppeliaStandin(answer_limit=100) as hung:
        command = [
            sys.executable,
            "-m",
            "membrane_cli",
            "coppelia",
            "--connect",
            membrane_server.address,
            "--sim-port",
            str(hung.port),
            "--sim-timeout",
            "0.5",
        ]
        result = subprocess.run(
            command, capture_output=True, text=True, timeout=60, env={**os.environ}
        )
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "did not answer within 0.5 s" in lines[0]


# -- the examples ---------------------------------------------------------------------------


def _example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, REPO / "examples" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_membrane_example_runs_100_steps_to_the_served_positions(
    standin: CoppeliaStandin, membrane_server: Any, membrane_client: Client
) -> None:
    example = _example("coppelia_membrane")
    argv = ["--connect", membrane_server.address, "--sim-port", str(standin.port)]
    assert example.main([*argv, "--steps", "100", "--keep"]) == 0
    scene, info = standin.scene, membrane_client.describe()
    assert scene.calls["sim.step"] == 100 and scene.calls["sim.callScriptFunction"] == 101
    spheres = {s.alias: s.handle for s in scene.of_kind("shape")}
    handles = [spheres[f"node{i}"] for i in range(info.n_points)]
    served = membrane_client.query(99 * info.dt)  # the frame shown at the 100th step
    expected = _expected_world(info, served.z)
    np.testing.assert_allclose(_positions_at_stop(scene, handles), expected, rtol=0, atol=1e-6)
    assert np.abs(expected[:, 2] - info.origin[2]).max() > 1e-3  # visibly displaced


def test_rope_example_per_sphere(
    standin: CoppeliaStandin, start_server: Callable[..., Any]
) -> None:
    server = start_server(["rope"])
    example = _example("coppelia_rope")
    argv = ["--connect", server.address, "--sim-port", str(standin.port), "--per-sphere"]
    assert example.main([*argv, "--steps", "10"]) == 0
    assert standin.scene.calls["sim.step"] == 10
    assert standin.scene.calls["sim.createPrimitiveShape"] == 100
    assert "sim.createScript" not in standin.scene.calls
    assert standin.scene.objects == {}


def test_example_exits_1_when_no_simulator_answers(membrane_server: Any) -> None:
    with CoppeliaStandin(answer_limit=0) as hung:
        example = _example("coppelia_membrane")
        argv = ["--connect", membrane_server.address, "--sim-port", str(hung.port)]
        assert example.main([*argv, "--sim-timeout", "0.3"]) == 1


# -- the benchmark --------------------------------------------------------------------------


@pytest.mark.slow
def test_benchmark_script_measures_both_paths(tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location(
        "coppelia_paths", REPO / "benchmarks" / "coppelia_paths.py"
    )
    assert spec is not None and spec.loader is not None
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    output = tmp_path / "figures.json"
    assert benchmark.main(["--steps", "3", "--round-trips", "20", "--json", str(output)]) == 0
    figures = json.loads(output.read_text())
    assert figures[BATCHED]["path"] == BATCHED and figures[PER_SPHERE]["path"] == PER_SPHERE
    assert figures[BATCHED]["spheres"] == figures[PER_SPHERE]["spheres"] == 400
    assert figures[BATCHED]["steps"] == figures[PER_SPHERE]["steps"] == 3
    assert figures["speedup_simulator_side_p50"] > 0
    assert set(figures["baseline_round_trip"]) == {"p50_ms", "p99_ms"}
