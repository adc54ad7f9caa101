"""The sphere lattice built, moved and removed in the stand-in's scene (real remote API client)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from lattice_checks import SIM_TIMEOUT, expected_world, lattice_on

from membrane_client import Client
from membrane_coppelia.batch_script import BATCH_FUNCTION
from membrane_coppelia.film import run_film
from membrane_coppelia.lattice import BATCHED, PER_SPHERE, LatticeStyle
from membrane_coppelia.link import SimulatorLink, connect_simulator
from membrane_coppelia.standin import CoppeliaStandin

# -- building the lattice -------------------------------------------------------------------


def test_build_places_the_described_lattice_under_one_parent(
    standin: CoppeliaStandin, link: SimulatorLink, membrane_client: Client
) -> None:
    style = LatticeStyle(sphere_size=0.04, color=(0.1, 0.2, 0.3), name="skin")
    lattice = lattice_on(link, membrane_client, style=style)
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
    np.testing.assert_allclose(rest, expected_world(info, np.zeros(info.n_points)), atol=1e-12)
    (script,) = scene.of_kind("script")
    assert lattice.path == BATCHED and script.parent == parent.handle
    assert script.script_initialized and f"function {BATCH_FUNCTION}(" in script.script_text
    lattice.remove()
    assert scene.objects == {}


def test_an_asynchronous_init_script_is_waited_for(membrane_client: Client) -> None:
    # The development line after 4.10 returns from sim.initScript before the script runs.
    with CoppeliaStandin(init_delay_passes=5) as standin:
        connection = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT)
        try:
            with lattice_on(connection, membrane_client) as lattice:
                lattice.build()
                assert lattice.path == BATCHED
        finally:
            connection.close()
        assert standin.scene.calls["sim.callScriptFunction"] > 1  # it had to ask again


def test_without_script_functions_it_falls_back_to_per_sphere(
    membrane_client: Client, caplog: pytest.LogCaptureFixture
) -> None:
    with CoppeliaStandin(scripts=False) as old:
        connection = connect_simulator("127.0.0.1", old.port, SIM_TIMEOUT)
        try:
            with (
                caplog.at_level(logging.WARNING),
                lattice_on(connection, membrane_client) as lattice,
            ):
                lattice.build()
                result = run_film(lattice, max_steps=2)
        finally:
            connection.close()
        assert result.path == PER_SPHERE and result.steps == 2
        assert "CoppeliaSim 4.9.0 has neither sim.createScript (4.7+) nor" in caplog.text
        assert old.scene.objects == {}


# -- removing it ----------------------------------------------------------------------------


def test_keep_leaves_the_lattice_in_the_scene(
    standin: CoppeliaStandin, link: SimulatorLink, membrane_client: Client
) -> None:
    with lattice_on(link, membrane_client, keep=True) as lattice:
        run_film(lattice, max_steps=1)
    assert len(standin.scene.of_kind("shape")) == 400
    assert not standin.scene.running
