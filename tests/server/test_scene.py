"""Scene files: built-ins, validation errors that name the field, lattices, model resolution."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import membrane_server.source
from membrane_client.protocol import MAX_LATTICE_POINTS
from membrane_server.scene import (
    Scene,
    SceneError,
    builtin_scenes,
    load_scene,
    scene_from_dict,
)
from membrane_server.source import resolve_source

BASE: dict[str, Any] = {
    "name": "s",
    "model": "membrane-forced",
    "evaluator": "exact",
    "lattice": {"nx": 4, "ny": 3},
    "dt": 0.01,
    "duration": 1.0,
}


def scene_with(**changes: Any) -> Scene:
    return scene_from_dict({**BASE, **changes})


def test_builtin_scenes_are_the_documented_ones() -> None:
    assert builtin_scenes() == [
        "membrane", "membrane-live", "rope", "rope-koopman", "rope-live", "rope-nonlinear",
        "rope-plucked", "skin-disk", "skin-patch", "skin-patch-nonlinear",
    ]  # fmt: skip


def test_rope_scene() -> None:
    scene = load_scene("rope")
    assert (scene.name, scene.model, scene.policy) == ("rope", "string-forced", "hold")
    assert scene.lattice.shape == (100,)
    assert (scene.dt, scene.duration, scene.steps) == (0.01, 1.0, 101)
    points = scene.lattice.coordinates([(0.0, 1.0)])
    np.testing.assert_allclose(points[:, 0], np.linspace(0.0, 1.0, 100))
    assert scene.placement.origin == (0.0, 0.0, 1.0)


def test_rope_plucked_scene_lasts_two_seconds() -> None:
    scene = load_scene("rope-plucked")
    assert (scene.model, scene.duration, scene.steps, scene.policy) == (
        "string-plucked", 2.0, 201, "hold",
    )  # fmt: skip


def test_membrane_scene() -> None:
    scene = load_scene("membrane")
    assert (scene.model, scene.policy, scene.steps) == ("membrane-forced", "hold", 101)
    assert scene.lattice.shape == (20, 20)


def test_grid_points_are_x_major() -> None:
    scene = scene_with(lattice={"nx": 3, "ny": 2})
    points = scene.lattice.coordinates([(0.0, 1.0), (0.0, 1.0)])
    expected = [[0, 0], [0, 1], [0.5, 0], [0.5, 1], [1, 0], [1, 1]]
    np.testing.assert_array_equal(points, expected)


def test_explicit_points() -> None:
    scene = scene_with(lattice={"points": [[0.1, 0.2], [0.5, 0.5], [0.9, 0.3]]})
    assert scene.lattice.shape == (3,)
    points = scene.lattice.coordinates([(0.0, 1.0), (0.0, 1.0)])
    np.testing.assert_array_equal(points[1], [0.5, 0.5])


def test_explicit_point_outside_the_domain_is_named() -> None:
    scene = scene_with(lattice={"points": [[0.1, 0.2], [1.5, 0.5]]})
    with pytest.raises(SceneError, match=r"lattice\.points\.1"):
        scene.lattice.coordinates([(0.0, 1.0), (0.0, 1.0)])


def test_lattice_of_the_wrong_dimension_is_refused() -> None:
    with pytest.raises(SceneError, match="give nx and ny"):
        scene_with(lattice={"nx": 10}).lattice.coordinates([(0.0, 1.0), (0.0, 1.0)])


@pytest.mark.parametrize(
    ("changes", "field", "reason"),
    [
        ({"lattice": {"nx": 0}}, "lattice.nx", "greater than or equal to 1"),
        ({"lattice": {"nx": 300, "ny": 300}}, "lattice", str(MAX_LATTICE_POINTS)),
        ({"lattice": {"nx": 3, "points": [[0.5]]}}, "lattice", "not both"),
        ({"lattice": {"ny": 3}}, "lattice", "give nx"),
        ({"lattice": {"points": [[0.1], [0.2, 0.3]]}}, "lattice.points", "coordinates"),
        ({"dt": -0.01}, "dt", "greater than 0"),
        ({"dt": math.nan}, "dt", "finite"),
        ({"duration": 1.005}, "duration", "whole number"),
        ({"dt": 2.0}, "duration", "whole number"),
        ({"evaluator": "fast"}, "evaluator", "network"),
        ({"policy": "wrap"}, "policy", "hold"),
        ({"snapping": "cubic"}, "snapping", "linear"),
        ({"placement": {"axis": "w"}}, "placement.axis", "'z'"),
        ({"placement": {"size": 0}}, "placement.size", "greater than 0"),
        ({"placement": {"origin": [0, 0]}}, "placement.origin.2", "Field required"),
        ({"evaluater": "exact"}, "evaluater", "Extra inputs"),
        ({"name": "bad name!"}, "name", "pattern"),
        ({"table_max_bytes": 0}, "table_max_bytes", "greater than 0"),
    ],
)
def test_validation_errors_name_the_field(changes: dict[str, Any], field: str, reason: str) -> None:
    with pytest.raises(SceneError) as caught:
        scene_with(**changes)
    message = str(caught.value)
    assert f"{field}:" in message
    assert reason in message


def test_missing_fields_are_named() -> None:
    with pytest.raises(SceneError) as caught:
        scene_from_dict({"name": "s"})
    for field in ("lattice", "dt", "duration"):
        assert f"{field}: Field required" in str(caught.value)
    complete = {"name": "s", "lattice": {"nx": 5}, "dt": 0.1, "duration": 1.0}
    for missing in ({}, {"model": "string-forced"}, {"model": "", "evaluator": "exact"}):
        with pytest.raises(SceneError, match=r"give model and evaluator .* or a \[tissue\]"):
            scene_from_dict({**complete, **missing})


def test_load_scene_from_file_defaults_name_to_stem(tmp_path: Path) -> None:
    path = tmp_path / "patch.toml"
    path.write_text(
        'model = "membrane-forced"\nevaluator = "exact"\ndt = 0.1\nduration = 1.0\n'
        "[lattice]\nnx = 5\nny = 5\n"
    )
    scene = load_scene(path)
    assert scene.name == "patch"
    assert scene.source == path.resolve()
    assert scene.steps == 11


def test_invalid_toml_is_a_scene_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("model = \n")
    with pytest.raises(SceneError, match="invalid TOML"):
        load_scene(path)


def test_unknown_builtin_lists_the_known_ones() -> None:
    known = (
        "membrane, membrane-live, rope, rope-koopman, rope-live, rope-nonlinear, rope-plucked, "
        "skin-disk, skin-patch, skin-patch-nonlinear"
    )
    with pytest.raises(SceneError, match=known):
        load_scene("skin")


def test_missing_file_is_a_scene_error(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match="cannot read scene"):
        load_scene(tmp_path / "nowhere.toml")


def test_relative_model_path_resolves_against_the_scene_file(
    tmp_path: Path, test_models: dict[str, Any]
) -> None:
    manifest = test_models["membrane"].manifest_path
    scene_file = manifest.parent / "local.toml"
    scene_file.write_text(
        f'model = "{manifest.name}"\nevaluator = "network"\ndt = 0.01\nduration = 1.0\n'
        "[lattice]\nnx = 3\nny = 3\n"
    )
    source = resolve_source(load_scene(scene_file))
    assert source.manifest is not None
    assert source.manifest.name == "membrane-test"
    assert source.problem.name == "membrane-forced"


def test_problem_name_without_zoo_model_needs_the_exact_evaluator(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(membrane_server.source, "list_models", list)  # an empty zoo
    with pytest.raises(SceneError, match="model: 'membrane-forced' is a problem with no trained"):
        resolve_source(scene_with(evaluator="network"))


def test_unknown_model_is_named() -> None:
    with pytest.raises(SceneError, match="model: unknown model 'no-such-model'"):
        resolve_source(scene_with(model="no-such-model", evaluator="network"))
