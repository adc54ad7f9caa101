"""MuJoCo coupled to a real `membrane serve --scene skin-patch`: a free tool dropped on the
patch rests where the tissue carries its weight, a tool driven at constant speed feels through
its actuator the force the session reports, and tools the contact cannot press are refused."""

from __future__ import annotations

from collections.abc import Iterator

import mujoco
import numpy as np
import pytest
from serve_process import ServeProcess

from membrane_client import Client
from membrane_client.errors import UserError
from membrane_client.live_schema import MAX_DEPTH, Probe
from membrane_client.session import Session
from membrane_mujoco import Coupler

pytestmark = pytest.mark.slow

MASS, RADIUS, G = 0.01, 0.003, 9.81
AT = (0.0263157894736842, 0.0263157894736842)  # the lattice point nearest the patch's centre


@pytest.fixture(scope="module")
def server() -> Iterator[ServeProcess]:
    process = ServeProcess("skin-patch")
    yield process
    process.close()


@pytest.fixture
def session(server: ServeProcess) -> Iterator[Session]:
    with Client(server.address) as client, client.session("skin-patch") as opened:
        yield opened


def _spec(body: str, option: str = 'timestep="0.0005"') -> mujoco.MjSpec:
    return mujoco.MjSpec.from_string(
        f"<mujoco><option {option}/><worldbody>{body}</worldbody></mujoco>"
    )


def test_a_dropped_tool_rests_where_the_tissue_carries_its_weight(
    server: ServeProcess, session: Session
) -> None:
    # 10 g, a 3 mm sphere, its lowest point 2 mm above the patch over one lattice point (its
    # neighbours, 2.6 mm away, stay clear of it): it lands at 0.2 m/s and settles within 1.5 s
    body = (
        f'<body name="tool" pos="{AT[0]} {AT[1]} 0.005"><freejoint/>'
        f'<geom name="tip" type="sphere" size="{RADIUS}" mass="{MASS}"/></body>'
    )
    coupler = Coupler(_spec(body), session, ["tip"], draw=False)
    forces = np.array([coupler.step().frame.tools[0].force for _ in range(2000)])
    depth = -(coupler.data.qpos[2] - RADIUS)  # the lowest point's, below the rest surface
    assert forces[-200:] == pytest.approx(MASS * G, rel=1e-3)  # at rest on the tissue
    assert forces[-200:].std() < 1e-4 * MASS * G
    assert np.abs(forces[1000:1100] - MASS * G).max() < 0.02 * MASS * G  # settled by 1 s
    static = _static_compliance(server.address)  # a point force's there (about 1 / 302 N/m)
    assert depth == pytest.approx(static * MASS * G, rel=0.02)


def _static_compliance(address: str) -> float:
    with Client(address) as client, client.session("skin-patch") as other:
        reading = other.step([], [Probe(AT, -MAX_DEPTH, 0.0)], frame=False).probes[0]
    return float(reading.static_compliance)


def test_an_actuator_driving_at_constant_speed_holds_the_reported_force(session: Session) -> None:
    # 50 g on a slide joint, no gravity, a velocity servo at -5 mm/s from 0.5 mm above, stiff
    # enough (5000 N s/m) that the speed it holds drops by under 1e-4 of it at 0.26 N
    body = (
        f'<body name="tool" pos="{AT[0]} {AT[1]} {RADIUS + 5e-4}">'
        '<joint name="z" type="slide" axis="0 0 1"/>'
        f'<geom name="tip" type="sphere" size="{RADIUS}" mass="0.05"/></body>'
    )
    xml = (
        '<mujoco><option timestep="0.0005" gravity="0 0 0" integrator="implicitfast"/>'
        f"<worldbody>{body}</worldbody>"
        '<actuator><velocity joint="z" kv="5000"/></actuator></mujoco>'
    )
    coupler = Coupler(mujoco.MjSpec.from_string(xml), session, ["tip"], draw=False)
    coupler.data.ctrl[0] = -0.005
    held, reported = [], []
    for _ in range(300):  # 0.3 s: 1 mm into the tissue
        step = coupler.step()
        held.append(-float(coupler.data.qfrc_actuator[0]))  # the servo pushes down
        reported.append(step.frame.tools[0].force)  # applied during the MuJoCo steps just taken
    held_n, reported_n = np.array(held), np.array(reported)
    pressed = reported_n > 0.05  # from 0.05 N on: past the first touch
    assert pressed.sum() > 50
    assert held_n[pressed] == pytest.approx(reported_n[pressed], rel=0.01)


def test_tools_the_contact_cannot_press_are_refused(session: Session) -> None:
    box = (
        '<body pos="0.02 0.02 0.01"><freejoint/>'
        '<geom name="block" type="box" size=".004 .004 .004"/></body>'
    )
    with pytest.raises(UserError, match="is a box: a tool is a sphere or a cylinder"):
        Coupler(_spec(box), session, ["block"], draw=False)
    with pytest.raises(
        UserError, match=r"no geom named 'tip' in the model \(named geoms: \['block'\]\)"
    ):
        Coupler(_spec(box), session, ["tip"], draw=False)
    tilted = (
        '<body pos="0.02 0.02 0.01" euler="0 30 0"><freejoint/>'
        '<geom name="punch" type="cylinder" size=".004 .004"/></body>'
    )
    coupler = Coupler(_spec(tilted), session, ["punch"], draw=False)
    with pytest.raises(UserError, match="tilted 30 deg from the scene's press axis"):
        coupler.step()
    with pytest.raises(UserError, match="longer than the scene's dt"):
        Coupler(_spec(box, 'timestep="0.002"'), session, ["block"], draw=False)


@pytest.fixture(scope="module")
def rope() -> Iterator[ServeProcess]:
    process = ServeProcess("rope-live")
    yield process
    process.close()


def test_a_gripper_holds_the_rope_where_its_site_is_and_feels_the_pull(rope: ServeProcess) -> None:
    # rope-live is dimensionless and drawn at 100 times its displacement: the grasp takes the
    # site's height in rope units, and the gripper feels the grasp's force at 100 N per unit
    xml = (
        '<mujoco><option timestep="0.0005" gravity="0 0 0" integrator="implicitfast"/>'
        '<worldbody><body name="gripper" pos="0.3 0 1"><joint name="lift" type="slide"/>'
        '<site name="jaw"/><geom type="box" size=".005 .005 .005" mass="0.05"/></body>'
        '</worldbody><actuator><position joint="lift" kp="20000" kv="400"/></actuator></mujoco>'
    )
    with Client(rope.address) as client, client.session("rope-live") as session:
        coupler = Coupler(
            mujoco.MjSpec.from_string(xml), session, grasps=["jaw"], force_scale=100.0
        )
        heights, held, pulled, actuated = [], [], [], []
        for n in range(400):
            coupler.data.ctrl[0] = 0.03 * min(1.0, n / 200)  # 3 cm up in 0.2 s, then held
            step = coupler.step()
            heights.append(step.grasps[0].height)
            held.append(step.frame.grasps[0].displacement)
            pulled.append(step.frame.grasps[0].force)
            actuated.append(float(coupler.data.qfrc_actuator[0]))
        site = float(coupler.data.site_xpos[0][2])
    assert np.array(held) == pytest.approx(np.array(heights), abs=1e-12)  # held where sent
    # the site's height in rope units (the servo yields a little to the rope's pull)
    assert heights[-1] == pytest.approx((site - 1.0) / 100, rel=1e-3)
    assert heights[-1] == pytest.approx(0.03 / 100, rel=0.05)
    force, servo = 100.0 * np.array(pulled[300:]), np.array(actuated[300:])
    assert force.min() > 5.0  # the rope pulls the gripper down: about 13 N at 100 N per unit
    assert servo == pytest.approx(force, rel=0.01)  # the servo holds what the rope pulls
