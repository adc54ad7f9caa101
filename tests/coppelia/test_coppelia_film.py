"""A film run in the stand-in against a real server: every sphere at the served frame, the run
ending with the scene or its policy."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from lattice_checks import expected_world, lattice_on, positions_at_stop

from membrane_client import Client
from membrane_coppelia.film import run_film
from membrane_coppelia.lattice import BATCHED, PER_SPHERE
from membrane_coppelia.link import SimulatorLink
from membrane_coppelia.standin import CoppeliaStandin


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


# -- running --------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("batched", [True, False], ids=[BATCHED, PER_SPHERE])
def test_run_moves_every_sphere_to_the_served_frame(
    standin: CoppeliaStandin, link: SimulatorLink, membrane_client: Client, batched: bool
) -> None:
    scene, info = standin.scene, membrane_client.describe()
    with lattice_on(link, membrane_client, batched=batched) as lattice:
        lattice.build()
        before = scene.calls.copy()
        result = run_film(lattice, max_steps=30)
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
    expected = expected_world(info, served.z)
    np.testing.assert_allclose(positions_at_stop(scene, handles), expected, rtol=0, atol=1e-6)
    assert result.last_positions is not None
    np.testing.assert_allclose(result.last_positions, expected, rtol=0, atol=1e-6)
    assert not scene.running and not any(standin.stepping_levels().values())
    timings = result.timings
    assert len(timings.read) == len(timings.query) == len(timings.move) == 30
    assert set(timings.percentiles()) == {"read", "query", "move", "step", "total"}


def test_default_run_ends_with_the_scene(
    standin: CoppeliaStandin, link: SimulatorLink, short_server: Any
) -> None:
    with (
        Client(short_server.address, timeout=5.0, scene="strict") as client,
        lattice_on(link, client) as lattice,
    ):
        result = run_film(lattice)
    assert (result.reason, result.steps) == ("completed", 6)
    assert result.last_t == pytest.approx(0.05, abs=1e-12)


def test_out_of_domain_under_policy_error_ends_the_run_cleanly(
    standin: CoppeliaStandin, link: SimulatorLink, short_server: Any
) -> None:
    with (
        Client(short_server.address, timeout=5.0, scene="strict") as client,
        lattice_on(link, client) as lattice,
    ):
        result = run_film(lattice, duration=0.2)
    assert result.reason == "out_of_domain" and result.steps == 6
    assert "stopped at t = 0.06 s" in result.message
    assert not standin.scene.running and standin.scene.objects == {}


def test_policy_hold_runs_past_the_end(
    standin: CoppeliaStandin, link: SimulatorLink, short_server: Any
) -> None:
    with (
        Client(short_server.address, timeout=5.0, scene="lenient") as client,
        lattice_on(link, client) as lattice,
    ):
        result = run_film(lattice, duration=0.1)
    assert (result.reason, result.steps) == ("completed", 11)
