"""CoppeliaSim 4.6 to 4.9: each version's calls, and a time step that did not take."""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from lattice_checks import SIM_TIMEOUT, expected_world, lattice_on, positions_at_stop

from membrane_client import Client
from membrane_coppelia.compat import SimCalls, SimVersion, TimeStepRefused
from membrane_coppelia.film import run_film
from membrane_coppelia.lattice import BATCHED
from membrane_coppelia.link import connect_simulator
from membrane_coppelia.standin import CoppeliaStandin


@pytest.mark.parametrize("version", ["4.6", "4.7", "4.8", "4.9"])
def test_each_version_runs_batched_with_the_calls_it_has(
    membrane_client: Client, version: str, caplog: pytest.LogCaptureFixture
) -> None:
    info = membrane_client.describe()
    with CoppeliaStandin(version=version) as standin:
        connection = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT)
        try:
            with (
                caplog.at_level(logging.WARNING),
                lattice_on(connection, membrane_client) as lattice,
            ):
                lattice.build()
                handles = list(lattice.handles)
                shapes = [standin.scene.objects[h] for h in handles]
                assert all(
                    s.int_params == {3003: 1, 3004: 1} for s in shapes
                )  # static, respondable
                result = run_film(lattice, max_steps=3)
        finally:
            connection.close()
        scene, calls = standin.scene, standin.scene.calls
    assert (result.path, result.steps, result.sim_dt) == (BATCHED, 3, info.dt)
    assert "batched moves unavailable" not in caplog.text
    served = membrane_client.query(result.last_t)
    expected = expected_world(info, served.z)
    np.testing.assert_allclose(positions_at_stop(scene, handles), expected, rtol=0, atol=1e-6)
    assert scene.objects == {} and not scene.running
    properties = version in ("4.8", "4.9")
    assert (calls["sim.setBoolProperty"] > 0) is properties
    assert (calls["sim.setObjectInt32Param"] > 0) is not properties
    assert (calls["sim.setFloatProperty"], calls["sim.setFloatParam"]) == (
        (1, 0) if properties else (0, 1)
    )
    if version == "4.6":  # scripts are no scene objects: attached, then removed as scripts
        assert calls["sim.addScript"] == calls["sim.associateScriptWithObject"] == 1
        assert calls["sim.removeScript"] == 1 and "sim.createScript" not in calls
    else:
        assert calls["sim.createScript"] == 1 and "sim.addScript" not in calls


class _StubSim:
    """A sim object whose time step call does nothing (as setFloatParam while running)."""

    floatparam_simulation_time_step = 1

    def __init__(self, returned: int = 0) -> None:
        self.dt, self.returned = 0.05, returned

    def setFloatParam(self, param: int, value: float) -> int:
        return self.returned

    def getSimulationTimeStep(self) -> float:
        return self.dt


def test_a_time_step_that_did_not_take_is_an_error() -> None:
    calls = SimCalls(_StubSim(), SimVersion(40700))
    assert not calls.properties and calls.scripts is None
    with pytest.raises(TimeStepRefused, match=r"CoppeliaSim 4.7.0 kept its time step at 0.05 s "):
        calls.set_time_step(0.001)
    with pytest.raises(TimeStepRefused, match=r"must be in \[0.0001, 10\] s .* dt is 5e-05 s"):
        calls.set_time_step(5e-5)


def test_versions_read_as_people_write_them() -> None:
    assert str(SimVersion(40902)) == "4.9.2" and SimVersion(41000).major_minor == (4, 10)
