"""The CoppeliaSim examples and the benchmark of the two move paths, against the stand-in."""

from __future__ import annotations

import importlib.util
import json
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from lattice_checks import expected_world, positions_at_stop

from membrane_client import Client
from membrane_coppelia.lattice import BATCHED, PER_SPHERE
from membrane_coppelia.standin import CoppeliaStandin

REPO = Path(__file__).resolve().parents[2]


# -- the examples ---------------------------------------------------------------------------


def _example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, REPO / "examples" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # over a second: the full suite runs it
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
    expected = expected_world(info, served.z)
    np.testing.assert_allclose(positions_at_stop(scene, handles), expected, rtol=0, atol=1e-6)
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
