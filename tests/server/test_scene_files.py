"""Scene files as a new user writes them: [parameters] for exact scenes, strict types, errors that
name the file, a stem that cannot be a name, motion too small to see, and the documented examples.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from membrane_models.exact import exact_solution
from membrane_models.problems import InvalidProblem, make_problem
from membrane_server.scene import Scene, SceneError, load_scene, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.source import resolve_source
from membrane_server.visibility import VISIBLE_FRACTION, invisible_motion, lattice_spacing

DOCS = Path(__file__).resolve().parents[2] / "docs"

BASE: dict[str, Any] = {
    "name": "s",
    "model": "membrane-forced",
    "evaluator": "exact",
    "lattice": {"nx": 6, "ny": 5},
    "dt": 0.01,
    "duration": 1.0,
}
SCENE_TEXT = 'model = "membrane-forced"\nevaluator = "exact"\ndt = 0.1\nduration = 1.0\n'
LATTICE_TEXT = "[lattice]\nnx = 5\nny = 5\n"


def scene_with(**changes: Any) -> Scene:
    return scene_from_dict({**BASE, **changes})


# -- [parameters] ------------------------------------------------------------------------------


def test_parameters_are_the_served_problems() -> None:
    parameters = {"c": 4, "x0": 0.6, "y0": 0.4, "h": 2.0}
    served = ServedScene.load(scene_with(parameters=parameters))
    assert served.describe()["model"]["parameters"] == {
        **make_problem("membrane-forced").parameters(),
        **{name: float(value) for name, value in parameters.items()},
    }
    expected = exact_solution(
        make_problem("membrane-forced", {k: str(v) for k, v in parameters.items()})
    ).on_points(served.evaluator.points)(0.5)
    default = ServedScene.load(scene_with()).evaluator.frame(0.5)
    frame = served.evaluator.frame(0.5)
    assert np.abs(frame - default).max() > 0.1 * np.abs(default).max()  # the parameters matter
    np.testing.assert_allclose(frame, np.asarray(expected).reshape(-1), rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize(
    ("parameters", "override"),
    [
        ({"c": -1}, ("c", "-1")),
        ({"x0": 1.5}, ("x0", "1.5")),
        ({"a": 0.5}, ("a", "0.5")),
        ({"wave_speed": 3}, ("wave_speed", "3")),
    ],
)
def test_parameters_are_checked_as_set_checks_them(
    parameters: dict[str, float], override: tuple[str, str]
) -> None:
    with pytest.raises(InvalidProblem) as by_set:
        make_problem("membrane-forced", dict([override]))
    with pytest.raises(SceneError) as caught:
        scene_with(parameters=parameters)
    assert f"parameters: {by_set.value}" in str(caught.value)


def test_parameters_names_are_case_insensitive_like_set() -> None:
    assert resolve_source(scene_with(parameters={"C": 7})).problem.parameters()["c"] == 7.0


def test_a_quoted_parameter_is_refused() -> None:
    with pytest.raises(SceneError, match=r"parameters\.c: Input should be a valid number, got the"):
        scene_with(parameters={"c": "4"})


@pytest.mark.parametrize(
    "changes",
    [{"evaluator": "network"}, {"model": "models/patch.json"}, {"model": "my-trained-model"}],
)
def test_parameters_go_with_an_exact_problem_only(changes: dict[str, Any]) -> None:
    with pytest.raises(SceneError, match="parameters: only for evaluator 'exact' with a problem"):
        scene_with(parameters={"c": 4}, **changes)


# -- strict types ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("changes", "field", "reason"),
    [
        ({"dt": "0.01"}, "dt", "got the string '0.01' (numbers go without quotes)"),
        ({"duration": "1"}, "duration", "got the string '1'"),
        ({"lattice": {"nx": 6.0, "ny": 5}}, "lattice.nx", "valid integer"),
        ({"lattice": {"nx": True, "ny": 5}}, "lattice.nx", "got the boolean true"),
        ({"placement": {"origin": [0, 0, "1"]}}, "placement.origin.2", "got the string '1'"),
        ({"placement": {"scale": "100"}}, "placement.scale", "got the string '100'"),
        ({"table_max_bytes": 1e6}, "table_max_bytes", "valid integer"),
        ({"name": 5}, "name", "valid string"),
    ],
)
def test_strict_types_refuse_what_lax_ones_converted(
    changes: dict[str, Any], field: str, reason: str
) -> None:
    with pytest.raises(SceneError) as caught:
        scene_with(**changes)
    assert f"{field}: " in str(caught.value) and reason in str(caught.value)


def test_whole_numbers_and_arrays_still_read_as_numbers_and_tuples() -> None:
    scene = scene_with(dt=0.5, duration=1, placement={"origin": [0, 1, 2], "scale": 100})
    assert scene.duration == 1.0 and scene.placement.origin == (0.0, 1.0, 2.0)
    assert scene.placement.scale == 100.0


# -- errors name the file ----------------------------------------------------------------------


def test_validation_error_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "patch.toml"
    path.write_text(SCENE_TEXT.replace("0.1", '"0.1"') + LATTICE_TEXT)
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    assert str(caught.value).startswith(f"scene {path.resolve()}: dt: ")


def test_model_error_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "patch.toml"
    text = SCENE_TEXT.replace('"membrane-forced"', '"no-such-model"')
    path.write_text(text.replace('"exact"', '"network"') + LATTICE_TEXT)
    with pytest.raises(SceneError) as caught:
        resolve_source(load_scene(path))
    assert str(caught.value).startswith(f"scene {path.resolve()}: model: unknown model")


@pytest.mark.parametrize(
    ("lattice", "reason"),
    [
        ("[lattice]\nnx = 5\n", "lattice: the model has 2 space axes, the lattice 1"),
        ("[lattice]\npoints = [[0.5, 1.5]]\n", "lattice.points.0: [0.5, 1.5] lies outside"),
    ],
)
def test_lattice_that_does_not_fit_the_model_names_the_file(
    tmp_path: Path, lattice: str, reason: str
) -> None:
    path = tmp_path / "patch.toml"
    path.write_text(SCENE_TEXT + lattice)
    with pytest.raises(SceneError) as caught:
        ServedScene.load(path)
    assert str(caught.value).startswith(f"scene {path.resolve()}: {reason}")


def test_scene_error_names_the_file_once(tmp_path: Path) -> None:
    path = tmp_path / "patch.toml"
    path.write_text(SCENE_TEXT + LATTICE_TEXT)
    scene = load_scene(path)
    where = f"scene {path.resolve()}"
    assert (
        str(scene.error(ValueError("table_max_bytes: too big")))
        == f"{where}: table_max_bytes: too big"
    )
    assert str(scene.error(ValueError(f"{where}: dt: x"))) == f"{where}: dt: x"
    assert str(scene.error(ValueError("scene patch: duration: y"))) == f"{where}: duration: y"
    assert str(scene_with().error(ValueError("lattice: z"))) == "scene s: lattice: z"


def test_a_whole_scene_check_is_not_given_a_made_up_field() -> None:
    with pytest.raises(SceneError) as caught:
        scene_with(start_offset=1e12, dt=1e-6, duration=1e-5)
    assert "scene s: start_offset: " in str(caught.value)
    assert ": scene: " not in str(caught.value)


# -- a stem that cannot be a name --------------------------------------------------------------


def test_a_stem_that_is_not_a_name_suggests_setting_name(tmp_path: Path) -> None:
    path = tmp_path / "my patch (v2).toml"
    path.write_text(SCENE_TEXT + LATTICE_TEXT)
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    message = str(caught.value)
    assert message.startswith(f"scene {path.resolve()}: name: the file's stem 'my patch (v2)'")
    suggestion = re.search(r'name = "([^"]+)"', message)
    assert suggestion is not None, message
    path.write_text(f'name = "{suggestion.group(1)}"\n' + SCENE_TEXT + LATTICE_TEXT)
    assert load_scene(path).name == suggestion.group(1) == "my-patch-v2"


# -- motion too small to see ------------------------------------------------------------------


def test_lattice_spacing_of_a_grid_and_of_a_single_point() -> None:
    grid = scene_with().lattice.coordinates([(0.0, 1.0), (0.0, 1.0)])
    assert lattice_spacing(grid) == pytest.approx(0.2)  # nx = 6: 1/5 (ny = 5 gives 1/4)
    assert lattice_spacing(np.array([[0.5, 0.5]])) is None


def test_default_scale_is_warned_about_and_the_builtin_scale_is_not() -> None:
    plain = ServedScene.load(scene_with(placement={"scale": 1.0}))
    warning = invisible_motion(plain.scene, plain.evaluator)
    assert warning is not None and warning.startswith("scene s: spheres move by at most")
    match = re.search(r"set placement.scale to ([0-9.e+-]+) or more", warning)
    assert match is not None, warning
    needed = float(match.group(1))
    scaled = ServedScene.load(scene_with(placement={"scale": needed * 1.01}))
    assert invisible_motion(scaled.scene, scaled.evaluator) is None
    peak = max(np.abs(scaled.evaluator.frame(k * 0.01)).max() for k in range(101))
    assert needed * peak == pytest.approx(VISIBLE_FRACTION * 0.2, rel=1e-2)  # 3 digits printed


@pytest.mark.parametrize("name", ["membrane", "rope", "rope-plucked"])
def test_builtin_scenes_move_visibly(name: str) -> None:
    served = ServedScene.load(name)
    assert invisible_motion(served.scene, served.evaluator) is None


# -- the documented scene files ----------------------------------------------------------------


def _documented_scenes() -> list[str]:
    """SCENES.md's whole scene files, and README's exact ones (its network one needs training)."""
    blocks = re.findall(r"```toml\n(.*?)```", (DOCS / "SCENES.md").read_text(), re.S)
    readme = (DOCS.parent / "README.md").read_text()
    blocks += re.findall(r"<<'TOML'\n(.*?)^TOML$", readme, re.S | re.M)
    return [b for b in blocks if "dt =" in b and 'evaluator = "exact"' in b]


def test_the_docs_show_whole_scene_files() -> None:
    assert len(_documented_scenes()) == 3


@pytest.mark.slow
@pytest.mark.parametrize("index", range(3))
def test_documented_scene_files_load_and_move_visibly(tmp_path: Path, index: int) -> None:
    path = tmp_path / "documented.toml"
    path.write_text(_documented_scenes()[index])
    served = ServedScene.load(load_scene(path))
    assert invisible_motion(served.scene, served.evaluator) is None
