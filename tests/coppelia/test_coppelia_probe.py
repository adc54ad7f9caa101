"""The live probe path: a scripted tool tip in the stand-in presses a live membrane server."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from membrane_cli.dispatcher import main as membrane_main
from membrane_client import Client, SceneInfo
from membrane_coppelia.lattice import BATCHED
from membrane_coppelia.link import ObjectNotFound
from membrane_coppelia.options import RunOptions
from membrane_coppelia.probe import TipMapping, drive_probe
from membrane_coppelia.standin import CoppeliaStandin

SIM_TIMEOUT = 5.0
REST_Z, SCALE = 1.0, 100.0  # membrane-live's placement: height 1, displacement x 100
DEPTH = 1e-3  # problem units: 0.1 world units at scale 100
STEPS = 150  # dt 1 ms: descend 10..60 ms, hold 60..110 ms, rise 110..130 ms


def _info(axis: str = "z", points: list[list[float]] | None = None) -> SceneInfo:
    grid = np.array(points or [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    return SceneInfo(
        name="s",
        description="",
        points=grid,
        shape=(grid.shape[0],),
        dt=0.001,
        duration=1.0,
        start_offset=0.0,
        steps=1001,
        origin=np.array([0.5, -1.0, 1.0]),
        size=2.0,
        scale=SCALE,
        axis=axis,
        policy="hold",
        snapping="nearest",
        evaluator="exact",
    )


# -- the tip's mapping: the inverse of the placement ----------------------------------------


def test_mapping_inverts_the_placement() -> None:
    info = _info()
    mapping = TipMapping.from_info(info)
    probe = mapping.probe((1.5, 0.0, 0.9), 0.05)
    assert probe is not None
    assert probe.at == pytest.approx((0.5, 0.5)) and probe.depth == pytest.approx(1e-3)
    # A lattice point pushed down by the probe's depth sits where the tip is.
    pressed = info.positions(np.array([0.0, 0.0, 0.0, -probe.depth]))[3]
    at_point = mapping.coordinates(pressed)
    assert at_point == pytest.approx(tuple(info.points[3])) and mapping.depth(pressed) == (
        pytest.approx(probe.depth)
    )


def test_a_tip_at_or_above_the_surface_makes_no_probe() -> None:
    mapping = TipMapping.from_info(_info())
    assert mapping.probe((1.5, 0.0, 1.0), 0.05) is None
    assert mapping.probe((1.5, 0.0, 1.3), 0.05) is None
    assert mapping.depth((1.5, 0.0, 1.3)) == pytest.approx(-0.003)


def test_mapping_on_another_axis_and_on_a_rope() -> None:
    sideways = TipMapping.from_info(_info(axis="y"))  # lattice on x and z, pressed along -y
    assert sideways.lateral == [0, 2]
    assert sideways.coordinates((2.5, -1.2, 3.0)) == pytest.approx((1.0, 1.0))
    assert sideways.depth((2.5, -1.2, 3.0)) == pytest.approx(0.2 / SCALE)
    rope = TipMapping.from_info(_info(points=[[0.0], [0.5], [1.0]]))
    assert rope.lateral == [0]
    assert rope.coordinates((1.5, 7.0, 0.0)) == pytest.approx((0.5,))  # across the rope: ignored


# -- the scripted tip against the stand-in and a live server --------------------------------


def _tip_height(t: float) -> float:
    """Above the surface, down to DEPTH below it, held, back up, above."""
    bottom = REST_Z - SCALE * DEPTH
    top = REST_Z + 0.02
    if t < 0.010:
        return top
    if t < 0.060:
        return top + (bottom - top) * (t - 0.010) / 0.050
    if t < 0.110:
        return bottom
    if t < 0.130:
        return bottom + (top - bottom) * (t - 0.110) / 0.020
    return top


def _scripted_tip(standin: CoppeliaStandin, xy: tuple[float, float]) -> int:
    scene = standin.scene
    tip = scene.create_dummy(0.01)
    scene.set_alias(tip, "tip")
    scene.set_position(tip, [xy[0], xy[1], _tip_height(0.0)], -1)
    scene.animate(tip, lambda t: (xy[0], xy[1], _tip_height(t)))
    return tip


def _nearest_point(info: SceneInfo, at: tuple[float, float]) -> int:
    return int(np.argmin(np.linalg.norm(info.points - np.array(at), axis=1)))


@pytest.mark.parametrize("version", ["4.9", "4.7"])
@pytest.mark.slow  # over a second: the full suite runs it
def test_the_sphere_under_the_tip_follows_it_in_contact(live_server: Any, version: str) -> None:
    with CoppeliaStandin(version=version) as standin:
        _press_and_check(live_server, standin)


def _press_and_check(live_server: Any, standin: CoppeliaStandin) -> None:
    with Client(live_server.address, timeout=5.0) as client:
        info = client.describe()
    index = _nearest_point(info, (0.5, 0.5))
    point = info.rest_positions()[index]
    tip = _scripted_tip(standin, (float(point[0]), float(point[1])))
    scene = standin.scene
    sphere_z: list[float] = []
    signal_values: list[float] = []

    def on_step(steps: int, t: float, force: float) -> None:
        spheres = {o.alias: o.handle for o in scene.of_kind("shape")}
        sphere_z.append(scene.world_position(spheres[f"node{index}"])[2])
        signal_values.append(_signal(standin, "tipForce"))

    options = RunOptions(
        server=live_server.address,
        server_timeout=5.0,
        sim_port=standin.port,
        sim_timeout=SIM_TIMEOUT,
        max_steps=STEPS,
    )
    result = drive_probe("/tip", options, force_signal="tipForce", on_step=on_step)
    assert (result.steps, result.reason, result.path) == (STEPS, "max_steps", BATCHED)
    assert result.sim_dt == info.dt == 0.001
    tips, forces = np.array(result.tips), np.array(result.forces)
    depths = np.array(result.depths)
    np.testing.assert_allclose(tips[:, :2], np.tile(point[:2], (STEPS, 1)), atol=1e-12)
    np.testing.assert_allclose(depths, (REST_Z - tips[:, 2]) / SCALE, atol=1e-12)
    above, contact = depths <= 0, forces > 0
    assert above.sum() > 20 and contact.sum() > 50  # the trajectory has both phases
    assert np.all(forces[above] == 0.0)  # out of contact: no force (no probe was sent)
    assert np.all(depths[contact] > 0)  # a force only with the tip below the surface
    # In contact the sphere under the tip goes where the tip goes: at or below its face (the
    # tissue's footprint-weighted mean is at the face, the point under the centre a little
    # lower) and within a quarter of the full depth of it.
    sphere, tip_z = np.array(sphere_z), tips[:, 2]
    gap = sphere - tip_z
    full = SCALE * DEPTH
    assert np.all(gap[contact] <= 1e-9) and np.all(gap[contact] > -0.25 * full)
    pressing = np.flatnonzero(contact & (np.diff(depths, prepend=0.0) > 0))  # tip going down
    assert len(pressing) > 20
    assert np.all(np.diff(sphere[pressing]) < 0)  # ... and the sphere with it
    settled = np.flatnonzero((depths > 0.999 * DEPTH) & contact)[-15:]  # held, at rest
    assert len(settled) == 15 and np.all(np.abs(gap[settled]) < 0.15 * full)
    assert np.all(sphere[settled] < REST_Z - 0.85 * full)
    # The force signal carries each step's force, and 0 after the run.
    np.testing.assert_allclose(signal_values, forces, rtol=0, atol=0)
    assert _signal(standin, "tipForce") == 0.0
    assert not scene.running and not standin.protocol.held()
    assert [o.alias for o in scene.objects.values()] == ["tip"]  # the lattice is gone
    assert tip in scene.objects


def _signal(standin: CoppeliaStandin, name: str) -> float:
    scene = standin.scene
    if scene.release.properties:
        return scene.properties.get(f"signal.{name}", float("nan"))
    return scene.signals.get(name, float("nan"))


def test_an_unknown_probe_object_is_bad_input(live_server: Any, standin: CoppeliaStandin) -> None:
    with pytest.raises(ObjectNotFound, match=r"no object '/nowhere' in CoppeliaSim's scene"):
        options = RunOptions(server=live_server.address, sim_port=standin.port, max_steps=1)
        drive_probe("/nowhere", options)
    assert standin.scene.objects == {} and not standin.scene.running


# -- the command line -----------------------------------------------------------------------


@pytest.mark.slow  # over a second: the full suite runs it
def test_cli_probe_run(
    live_server: Any, standin: CoppeliaStandin, capsys: pytest.CaptureFixture[str]
) -> None:
    _scripted_tip(standin, (0.5, 0.5))
    argv = ["coppelia", "--connect", live_server.address, "--sim-port", str(standin.port)]
    probe = ["--probe", "/tip", "--force-signal", "f", "--steps", "80"]
    assert membrane_main([*argv, *probe]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("scene membrane-live: 400 spheres moved batched, pressed by /tip:")
    assert "80 steps (max_steps), in contact for " in lines[0]
    assert "peak force " in lines[0] and "in contact for 0," not in lines[0]
    assert lines[2] == (
        "contact force written each step with "
        "sim.setFloatProperty(sim.handle_scene, 'signal.f', value)"
    )


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--force-signal", "f"], "--force-signal needs --probe"),
        (["--probe", "/nowhere"], "no object '/nowhere'"),
        (["--probe", "/tip", "--force-signal", "no way"], "a signal name is letters"),
        (["--probe", "/tip"], "not_live"),
    ],
)
def test_cli_probe_bad_input_exits_2(
    live_server: Any,
    membrane_server: Any,
    standin: CoppeliaStandin,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    _scripted_tip(standin, (0.5, 0.5))
    server = membrane_server if message == "not_live" else live_server  # a film: not live
    argv = ["coppelia", "--connect", server.address, "--sim-port", str(standin.port)]
    assert membrane_main([*argv, *extra, "--steps", "2"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not standin.scene.running and [o.alias for o in standin.scene.of_kind("shape")] == []
