"""The simulation in stepping mode: the scene's time step set, and said so once."""

from __future__ import annotations

import logging

import pytest

pytest.importorskip("coppeliasim_zmqremoteapi_client")

from lattice_checks import lattice_on

from membrane_client import Client
from membrane_coppelia.film import run_film
from membrane_coppelia.link import SimulatorLink
from membrane_coppelia.standin import CoppeliaStandin


def test_changing_the_simulators_time_step_is_logged_once(
    standin: CoppeliaStandin,
    link: SimulatorLink,
    membrane_client: Client,
    caplog: pytest.LogCaptureFixture,
) -> None:
    dt = membrane_client.describe().dt
    assert standin.scene.dt != dt  # the stand-in starts at CoppeliaSim's default, 0.05 s
    with caplog.at_level(logging.WARNING), lattice_on(link, membrane_client) as lattice:
        run_film(lattice, max_steps=1)
        run_film(lattice, max_steps=1)  # already at the scene's dt: nothing more to say
    changes = [r.getMessage() for r in caplog.records if "time step" in r.getMessage()]
    assert changes == [
        f"changed the simulator's time step from 0.05 s to {dt:g} s (the scene's dt); "
        "it stays so after the run"
    ]
