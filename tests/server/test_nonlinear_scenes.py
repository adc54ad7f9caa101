"""The nonlinear scenes served: `skin-patch-nonlinear` (the reduced von Karman plate under
rigid tools) and `rope-nonlinear` (the Kirchhoff-Carrier string), over real sockets.

The reduced plate is built once into a temporary cache (about 5 s on two cores), so the plate's
tests are marked slow."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from membrane_client import Client, Grasp, Probe, Tool
from membrane_client.errors import ServerError
from membrane_models.fem.nonlinear_engine import NonlinearPlateEngine
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.scene import SCENES_DIR, SceneError
from membrane_server.served import ServedScene
from membrane_server.server import Server


def _serving(*names: str) -> Server:
    server = Server([ServedScene.load(name) for name in names], bind="tcp://127.0.0.1:*")
    server.start()
    return server


@pytest.mark.slow
def test_the_nonlinear_skin_patch_is_pressed_by_tools_over_the_wire(cache_dir: Path) -> None:
    server = _serving("skin-patch-nonlinear")
    try:
        with Client(server.address, timeout=20.0) as client:
            live = client.describe("skin-patch-nonlinear").live
            assert live["engine"] == "fem-nonlinear" and live["inplane"] == "held"
            assert live["modes"] == 20 and live["max_depth"] == pytest.approx(0.012)
            with client.session("skin-patch-nonlinear") as session:
                frame = None
                for k in range(1, 301):  # 3 mm over 0.3 s
                    tool = Tool("sphere", (0.025, 0.025), 0.003 * k / 300, 0.005)
                    frame = session.step(tools=[tool])
                assert frame is not None
                reading = frame.tools[0]
                assert reading.force > 0.5 and reading.contacts > 0  # measured 1.13 N
                assert reading.penetration < 1e-12
                assert np.asarray(frame.z).min() == pytest.approx(-0.003, abs=5e-4)
                with pytest.raises(ServerError, match="takes"):
                    session.step(probes=[Probe((0.025, 0.025), 0.001, 0.0)])
                with pytest.raises(ServerError, match="no longer moderate"):
                    session.step(tools=[Tool("sphere", (0.025, 0.025), 0.02, 0.005)])
    finally:
        server.stop()


@pytest.mark.slow
def test_steps_that_wait_for_builds_are_taken_in_process_and_refused_by_a_server(
    cache_dir: Path, tmp_path: Path
) -> None:
    # adapted_build = "wait" holds the step for a tool vector's build: a server refuses the
    # scene (it would hold every client), one process steps it, every session alike
    text = (SCENES_DIR / "skin-patch-nonlinear.toml").read_text()
    path = tmp_path / "skin-wait.toml"
    path.write_text(text.replace('inplane = "held"', 'inplane = "held"\nadapted_build = "wait"'))
    with pytest.raises(SceneError, match=r"skin-wait\.toml: .* would hold every client's requests"):
        Server([str(path)], bind="tcp://127.0.0.1:*")
    served = ServedScene.load(path)
    try:
        transport = InProcessTransport(Dispatcher([served]))
        with Client("in-process://skin-wait", transport=transport) as client:
            forces = []
            for _ in range(2):  # the first waits for the build, the second finds it built
                with client.session("skin-wait") as session:
                    tool = Tool("sphere", (0.025, 0.025), 0.002, 0.005)
                    forces.append(session.step(tools=[tool], frame=False).tools[0].force)
        assert forces[0] == forces[1] and forces[0] > 0.1  # measured 0.437 N by step 45
    finally:
        assert isinstance(served.live, NonlinearPlateEngine)
        served.live.close()


def test_the_nonlinear_rope_takes_probes_grasps_and_tools_over_the_wire() -> None:
    server = _serving("rope-nonlinear")
    try:
        with Client(server.address, timeout=10.0) as client:
            live = client.describe("rope-nonlinear").live
            assert live["engine"] == "kirchhoff" and live["stretch"] == 100.0
            assert live["dt"] == 0.001 and live["lattice"] == [130]
            with client.session("rope-nonlinear") as session:
                grasped = session.step(grasps=[Grasp((0.3,), 0.05, 0.02)])
                assert grasped.grasps[0].force > 0.0
                pressed = session.step(tools=[Tool("cylinder", (0.6,), 0.01, 0.03)])
                assert pressed.tools[0].force > 0.0
                probed = session.step(probes=[Probe((0.6,), 0.03, 0.02)])
                assert probed.probes[0].in_contact
    finally:
        server.stop()
