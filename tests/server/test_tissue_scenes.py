"""Physical scenes: a [tissue] table served live in SI units, with no film.

The built-in ``skin-patch`` (the study's 50 mm clamped plate) and ``skin-disk`` (a simply
supported disk of skin) are built once per module into a temporary cache (about 10 s on two
cores), so the tests here are marked slow; the table's refusals need no build and stay fast.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from membrane_client import Client, Probe
from membrane_client.errors import ServerError
from membrane_models.live import Probe as EngineProbe
from membrane_models.live import Tool as EngineTool
from membrane_server.scene import SceneError, load_scene, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.server import Server

SIDE = 0.05
RIGIDITY = 1.5e6 * 0.003**3 / (12 * (1 - 0.45**2))  # N m


@pytest.fixture(scope="module")
def skin_patch(cache_dir: Path) -> ServedScene:
    return ServedScene.load("skin-patch")


def _pressed(scene: ServedScene, at: tuple[float, float], depth: float) -> float:
    """The force (N) of a point probe pressed slowly to ``depth`` (m) and held."""
    engine = scene.live
    assert engine is not None
    state = engine.start().state
    for k in range(600):
        probe = EngineProbe(at, depth * min(1.0, (k + 1) / 300), 0.0)
        result = engine.step(state, [], [probe], frame=False)
        state = result.state
    return float(result.probes[0].force)


@pytest.mark.slow
def test_skin_patch_describes_itself_in_si_units(skin_patch: ServedScene) -> None:
    described = skin_patch.describe()
    assert described["film"] is False and described["extent"] == {
        "lower": [0.0, 0.0],
        "upper": [SIDE, SIDE],
    }
    assert described["units"]["displacement"].startswith("m") and described["units"]["force"] == "N"
    material = described["model"]["material"]
    assert material["rigidity_n_m"] == pytest.approx(RIGIDITY, rel=1e-12)
    assert described["model"]["supports"] == "clamped"
    live = described["live"]
    assert live["engine"] == "fem" and live["modes_stepped"] == 100 and live["radii"] == [0.0]
    assert live["units"]["depth"].startswith("m below")
    points = np.asarray(skin_patch.evaluator.points)
    assert points.min() == 0.0 and points.max() == pytest.approx(SIDE)
    frame = skin_patch.query(0.5)  # no film: the rest shape, at any time
    assert not np.any(skin_patch.frame(skin_patch.timeline.resolve(0.5)))
    assert frame["scene"] == "skin-patch"
    # The lattice as a surface for a viewer: the 20 x 20 grid's cells, all on the square.
    triangles = np.asarray(described["triangles"]).reshape(-1, 3)
    assert triangles.shape == (2 * 19 * 19, 3) and triangles.max() == 399


@pytest.mark.slow
def test_a_rigid_tool_over_a_node_needs_the_point_probes_force(skin_patch: ServedScene) -> None:
    """A 1 mm flat tool over one lattice node holds that node's deflection with point forces,
    as a point probe there does: the same force within 1 % (measured 0.18 %: the probe reads
    the tables' interpolated point, the tool the lattice's node)."""
    engine = skin_patch.live
    assert engine is not None
    node = 9 * 20 + 9
    x, y = (float(c) for c in engine.basis.lattice_coordinates[node])  # type: ignore[attr-defined]
    at = (x, y)
    state = engine.start().state
    for k in range(600):
        tool = EngineTool("cylinder", at, 1e-4 * min(1.0, (k + 1) / 300), 1e-3)
        result = engine.step(state, [], [], frame=False, tools=[tool])  # type: ignore[call-arg]
        state = result.state
    assert result.tools[0].force == pytest.approx(_pressed(skin_patch, at, 1e-4), rel=1e-2)


@pytest.mark.slow
def test_a_point_probe_needs_the_clamped_plates_point_stiffness(skin_patch: ServedScene) -> None:
    """Pressed slowly at the centre and held: F = d / (0.005612 a^2 / D) within 1 %."""
    depth = 1e-4
    compliance = 0.005612 * SIDE**2 / RIGIDITY  # 3.315 mm/N
    assert _pressed(skin_patch, (SIDE / 2, SIDE / 2), depth) == pytest.approx(
        depth / compliance, rel=1e-2
    )


@pytest.mark.slow
def test_the_skin_disk_is_the_simply_supported_disk(cache_dir: Path) -> None:
    scene = ServedScene.load("skin-disk")
    radius, nu = 0.02, 0.45
    compliance = (3 + nu) / (1 + nu) * radius**2 / (16 * math.pi * RIGIDITY)
    force = _pressed(scene, (radius, radius), 1e-4)
    assert force == pytest.approx(1e-4 / compliance, rel=1e-2)
    assert scene.describe()["model"]["shape"]["kind"] == "disk"


@pytest.mark.slow
def test_served_in_si_with_strict_refusals(skin_patch: ServedScene) -> None:
    server = Server([skin_patch], bind="tcp://127.0.0.1:*")
    server.start()
    try:
        with Client(server.address, timeout=10.0) as client, client.session("skin-patch") as s:
            frame = s.step(probes=[Probe((0.025, 0.025), 1e-5, 0.0)])
            assert frame.probes[0].in_contact and frame.probes[0].force > 0
            outside = s.step(probes=[Probe((0.06, 0.025), 0.0, 0.0)])
            assert outside.probes[0].outside  # without strict: touches nothing
            with pytest.raises(
                ServerError, match=r"outside the domain \[0, 0.05\] x \[0, 0.05\] m"
            ):
                s.step(probes=[Probe((0.06, 0.025), 0.0, 0.0)], strict=True)
    finally:
        server.stop()


def _tissue_scene(**tissue: object) -> dict[str, object]:
    table: dict[str, object] = {
        "kind": "plate",
        "shape": "rectangle",
        "size": [0.05, 0.05],
        "element_size": 0.01,
        "youngs_modulus": 1.5e6,
        "poisson": 0.45,
        "thickness": 0.003,
        "density": 1109.0,
    }
    table.update(tissue)
    return {
        "name": "t",
        "dt": 0.001,
        "tissue": table,
        "lattice": {"nx": 5, "ny": 5},
        "live": {},
    }


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"thickness": None}, "a plate needs thickness"),
        ({"kind": "membrane"}, "a membrane needs tension"),
        ({"shape": "disk", "size": [0.04, 0.02]}, "a disk needs size"),
        ({"radii": [0.2]}, "radii must be from 0 to 0.1 m"),
        ({"damping": 0.1, "rayleigh": [1.0, 0.0]}, "not both"),
        ({"colour": "pink"}, "tissue.colour"),
    ],
)
def test_a_bad_tissue_table_is_refused_naming_its_field(
    change: dict[str, object], message: str
) -> None:
    data = _tissue_scene(**change)
    tissue = data["tissue"]
    assert isinstance(tissue, dict)
    for key, value in change.items():
        if value is None:
            del tissue[key]
    with pytest.raises(SceneError, match=message):
        scene_from_dict(data)


def test_a_tissue_scene_names_no_model_and_a_film_scene_needs_one() -> None:
    with pytest.raises(SceneError, match="names no model"):
        scene_from_dict({**_tissue_scene(), "model": "membrane-forced", "evaluator": "exact"})
    with pytest.raises(SceneError, match="give model and evaluator"):
        scene_from_dict({"name": "f", "dt": 0.01, "duration": 1.0, "lattice": {"nx": 5}})
    with pytest.raises(SceneError, match="is live"):
        scene_from_dict({k: v for k, v in _tissue_scene().items() if k != "live"})
    assert load_scene("skin-patch").film is False and load_scene("membrane").film is True


def test_a_live_scene_without_a_duration_builds_no_film() -> None:
    scene = scene_from_dict(
        {
            "name": "poke-only",
            "model": "membrane-forced",
            "evaluator": "exact",
            "dt": 0.001,
            "lattice": {"nx": 12, "ny": 12},
            "live": {"damping": 0.02},
        }
    )
    assert scene.film is False and scene.duration == scene.dt
    served = ServedScene.load(scene)
    assert served.evaluator.kind == "rest"  # nothing built for a film nobody asked for
    described = served.describe()
    assert described["film"] is False and described["steps"] == 2
    assert described["extent"] == {"lower": [0.0, 0.0], "upper": [1.0, 1.0]}
    assert described["units"]["displacement"].startswith("problem units")
    assert not np.any(served.frame(served.timeline.resolve(0.7)))
    engine = served.live
    assert engine is not None
    result = engine.step(engine.start().state, [], [EngineProbe((0.5, 0.5), 1e-4, 0.05)])
    assert result.probes[0].in_contact
    with pytest.raises(SceneError, match="only a live scene goes without a film"):
        scene_from_dict({**scene.model_dump(exclude={"source"}), "live": None, "film": False})
