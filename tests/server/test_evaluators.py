"""Each evaluator against its reference: the full ONNX graph run directly, or the exact solution."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import pytest
from onnx_graphs import reference_full

from membrane_models.artifacts.manifest import ManifestError
from membrane_models.exact import exact_solution
from membrane_models.problems import make_problem
from membrane_server.evaluators import (
    Evaluator,
    ExactEvaluator,
    TableEvaluator,
    build_evaluator,
)
from membrane_server.runtime import OPTIMIZATION_LEVELS, session_options
from membrane_server.scene import Scene, SceneError, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.source import ModelSource, resolve_source

GRID_TIMES = [0.0, 0.01, 0.25, 0.5, 0.73, 1.0]


def build(scene: Scene, **options: Any) -> Evaluator:
    """The scene's evaluator, its model resolved once as ``ServedScene.load`` does."""
    return build_evaluator(scene, resolve_source(scene), **options)


def relative_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(a, np.float64) - b) / np.linalg.norm(b))


def full_graph(model: Any, points: np.ndarray, t: float) -> np.ndarray:
    """The model's full graph, run directly with onnxruntime (default options)."""
    session = ort.InferenceSession(str(model.full_path), providers=["CPUExecutionProvider"])
    xt = np.hstack([points, np.full((points.shape[0], 1), t)]).astype(np.float32)
    return np.asarray(session.run(None, {"xt": xt})[0], dtype=np.float64).reshape(-1)


def test_test_graphs_compute_what_they_claim(test_models: dict[str, Any]) -> None:
    rng = np.random.default_rng(7)
    for model in test_models.values():
        points = rng.random((64, model.spatial_dims))
        for t in (0.1, 0.6, 0.95):
            reference = reference_full(model, points, t)
            assert relative_l2(full_graph(model, points, t), reference) < 1e-5


@pytest.mark.parametrize("kind", ["network", "separable", "table"])
@pytest.mark.parametrize("t", GRID_TIMES)
def test_onnx_evaluators_match_the_full_graph(
    evaluator_scenes: dict[str, ServedScene], test_models: dict[str, Any], kind: str, t: float
) -> None:
    evaluator = evaluator_scenes[kind].evaluator
    model = test_models["membrane"]
    reference = full_graph(model, evaluator.points, t)
    if t > 0.0:  # a time-dependent signal beside the constant bias (zero at t = 0 by design)
        assert np.abs(reference - model.bias).max() > 1e-3 * np.abs(reference).max()
    assert relative_l2(evaluator.frame(t), reference) <= 1e-6


@pytest.mark.parametrize("t", GRID_TIMES)
def test_separable_matches_network_per_frame(
    evaluator_scenes: dict[str, ServedScene], t: float
) -> None:
    separable = evaluator_scenes["separable"].evaluator.frame(t)
    network = evaluator_scenes["network"].evaluator.frame(t)
    assert relative_l2(separable, np.asarray(network, np.float64)) <= 1e-6


def test_one_dimensional_models(test_models: dict[str, Any], make_scene: Any) -> None:
    model = test_models["string"]
    for kind in ("network", "separable", "table"):
        scene = make_scene(model.manifest_path, kind, lattice={"nx": 100})
        evaluator = build(scene)
        assert evaluator.points.shape == (100, 1)
        reference = full_graph(model, evaluator.points, 0.5)
        assert relative_l2(evaluator.frame(0.5), reference) <= 1e-6


@pytest.mark.parametrize("t", GRID_TIMES)
def test_exact_evaluator_matches_the_exact_solution(
    evaluator_scenes: dict[str, ServedScene], t: float
) -> None:
    evaluator = evaluator_scenes["exact"].evaluator
    solution = exact_solution(make_problem("membrane-forced"))
    reference = solution.at_points(evaluator.points, np.array([t]))[:, 0]
    frame = evaluator.frame(t)
    if t == 0.0:
        np.testing.assert_array_equal(frame, 0.0)  # zero initial displacement
    else:
        assert relative_l2(frame, reference) <= 1e-8


def test_exact_grid_frames_equal_frames_on_demand(evaluator_scenes: dict[str, ServedScene]) -> None:
    evaluator = evaluator_scenes["exact"].evaluator
    assert evaluator.info()["precomputed_frames"] == 101
    on_demand = ExactEvaluator(make_problem("membrane-forced"), evaluator.points)
    assert on_demand.info()["precomputed_frames"] == 0
    for t in (0.3, 0.77):
        np.testing.assert_array_equal(evaluator.frame(t), on_demand.frame(t))
    off_grid = evaluator.frame(0.3333)  # off the grid: computed, not interpolated
    np.testing.assert_array_equal(off_grid, on_demand.frame(0.3333))


@pytest.mark.parametrize("problem", ["string-forced", "string-plucked"])
def test_exact_evaluator_on_strings(problem: str) -> None:
    points = np.linspace(0.0, 1.0, 50)[:, None]
    evaluator = ExactEvaluator(make_problem(problem), points)
    reference = exact_solution(make_problem(problem)).at_points(points, np.array([0.5]))[:, 0]
    assert relative_l2(evaluator.frame(0.5), reference) <= 1e-8
    assert evaluator.info()["kind"] == "exact"


def test_table_reports_memory_and_interpolates(evaluator_scenes: dict[str, ServedScene]) -> None:
    table = evaluator_scenes["table"].evaluator
    assert isinstance(table, TableEvaluator)
    info = table.info()
    assert info["frames"] == 101
    assert info["memory_bytes"] == 101 * 400 * 4
    assert info["source"] == "separable"
    between = table.frame(0.2525)
    expected = 0.75 * table.frame(0.25).astype(np.float64) + 0.25 * table.frame(0.26)
    np.testing.assert_allclose(between, expected, rtol=1e-6, atol=1e-12)


def test_table_over_a_full_only_model_uses_the_network(
    test_models: dict[str, Any], make_scene: Any
) -> None:
    model = test_models["membrane_full_only"]
    evaluator = build(make_scene(model.manifest_path, "table", dt=0.1))
    assert evaluator.info()["source"] == "network"
    reference = full_graph(model, evaluator.points, 0.3)
    assert relative_l2(evaluator.frame(0.3), reference) <= 1e-6


def test_table_memory_limit_is_enforced(test_models: dict[str, Any], make_scene: Any) -> None:
    scene = make_scene(test_models["membrane"].manifest_path, "table", table_max_bytes=10_000)
    with pytest.raises(SceneError, match=r"table_max_bytes: .* 161600 bytes"):
        build(scene)


def test_separable_needs_part_graphs(test_models: dict[str, Any], make_scene: Any) -> None:
    scene = make_scene(test_models["membrane_full_only"].manifest_path, "separable")
    with pytest.raises(SceneError, match="no space/time part-graphs"):
        build(scene)


def test_network_refuses_durations_past_the_trained_domain(
    test_models: dict[str, Any], make_scene: Any
) -> None:
    scene = make_scene(test_models["membrane"].manifest_path, "network", duration=10.0)
    with pytest.raises(SceneError, match=r"duration: 10.0 s reaches past"):
        build(scene)


def test_lattice_dimension_must_match_the_model(
    test_models: dict[str, Any], make_scene: Any
) -> None:
    scene = make_scene(test_models["string"].manifest_path, "network")  # 20 x 20 on a string
    with pytest.raises(SceneError, match="lattice"):
        build(scene)


def test_altered_graph_is_refused_at_load(
    test_models: dict[str, Any], make_scene: Any, tmp_path: Path
) -> None:
    source = test_models["membrane"].manifest_path.parent
    for path in source.glob("membrane-test*"):
        shutil.copy(path, tmp_path / path.name)
    with (tmp_path / "membrane-test.time.onnx").open("ab") as handle:
        handle.write(b"\x00")
    scene = make_scene(tmp_path / "membrane-test.json", "separable")
    with pytest.raises(ManifestError, match="sha256"):
        build(scene)


def test_optimisation_levels_are_onnxruntime_s_and_the_default_is_all() -> None:
    levels = ort.GraphOptimizationLevel
    expected = ["ORT_ENABLE_ALL", "ORT_ENABLE_EXTENDED", "ORT_ENABLE_BASIC", "ORT_DISABLE_ALL"]
    chosen = [session_options(1, name).graph_optimization_level for name in OPTIMIZATION_LEVELS]
    assert chosen == [getattr(levels, name) for name in expected]
    assert session_options().graph_optimization_level == levels.ORT_ENABLE_ALL
    with pytest.raises(ValueError, match="'fastest': expected one of all, extended"):
        session_options(1, "fastest")


@pytest.mark.parametrize("kind", ["network", "separable"])
def test_graphs_at_another_optimisation_level_give_the_same_frames(
    evaluator_scenes: dict[str, ServedScene], make_scene: Any, test_models: dict[str, Any],
    kind: str,
) -> None:  # fmt: skip
    scene = make_scene(test_models["membrane"].manifest_path, kind)
    unoptimised = build(scene, optimization="disabled", threads=2)
    served = evaluator_scenes[kind].evaluator
    for t in (0.25, 0.73):
        assert relative_l2(unoptimised.frame(t), np.asarray(served.frame(t), np.float64)) <= 1e-6


def test_exact_evaluator_with_a_tolerance_per_query() -> None:
    scene = scene_from_dict({
        "name": "exact", "model": "membrane-forced", "evaluator": "exact",
        "lattice": {"nx": 10, "ny": 10}, "dt": 0.01, "duration": 1.0,
    })  # fmt: skip
    default = build(scene)
    truncated = build(scene, rtol=1e-3, on_demand=True)
    info, default_info = truncated.info(), default.info()
    assert "rtol" not in default_info and default_info["precomputed_frames"] == 101
    assert info["rtol"] == 1e-3 and info["precomputed_frames"] == 0
    assert 0 < info["modes"] < default_info["modes"]
    error = relative_l2(truncated.frame(0.5), default.frame(0.5))
    assert 1e-6 < error < 1e-2  # a series cut at 1e-3 is wrong by about that much
    with pytest.raises(ValueError, match="rtol"):
        build(scene, rtol=-1.0)


def test_a_bare_problem_is_served_as_a_table_of_its_exact_solution(make_scene: Any) -> None:
    """No scene file says this (there a problem's name with ``table`` means its zoo model):
    ``membrane tradeoff`` passes the bare problem as the resolved source."""
    source = ModelSource(problem=make_problem("membrane-forced"))
    table = build_evaluator(make_scene("membrane-forced", "table"), source, rtol=1e-6)
    info = table.info()
    assert (info["source"], info["frames"], info["memory_bytes"]) == ("exact", 101, 101 * 400 * 8)
    reference = ExactEvaluator(make_problem("membrane-forced"), table.points, rtol=1e-6)
    np.testing.assert_array_equal(table.frame(0.5), reference.frame(0.5))
    with pytest.raises(SceneError, match="'network' needs a trained model"):
        build_evaluator(make_scene("membrane-forced", "network"), source)
