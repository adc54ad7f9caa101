"""The server's fixtures (tests/helpers/server_fixtures.py): the adapter talks to a live server.

Plus the live scenes the probe path presses, one server each for the whole folder (building a
live engine takes a moment; sessions keep the tests apart); and a stand-in per test, with a
connection to it and a membrane client (imported when used: without the ``coppelia`` extra the
test modules skip themselves).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pytest
from server_fixtures import (  # noqa: F401 (fixtures register by name)
    LOOPBACK_ANY_PORT,
    make_scene,
    membrane_server,
    start_server,
)

from membrane_client import Client
from membrane_server.server import Server

if TYPE_CHECKING:
    from membrane_coppelia.link import SimulatorLink
    from membrane_coppelia.standin import CoppeliaStandin


def _serve(scene: str) -> Iterator[Server]:
    server = Server([scene], bind=LOOPBACK_ANY_PORT)
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="session")
def live_server() -> Iterator[Server]:
    """A server on the built-in live scene 'membrane-live' (20 x 20, dt 1 ms)."""
    yield from _serve("membrane-live")


@pytest.fixture(scope="session")
def rope_server() -> Iterator[Server]:
    """A server on the built-in live scene 'rope-live' (100 points, dt 1 ms)."""
    yield from _serve("rope-live")


@pytest.fixture
def standin() -> Iterator[CoppeliaStandin]:
    """A stand-in at dt 0.05 s, CoppeliaSim's default: the adapter sets the scene's."""
    from membrane_coppelia.standin import CoppeliaStandin

    with CoppeliaStandin() as server:
        yield server


@pytest.fixture
def link(standin: CoppeliaStandin) -> Iterator[SimulatorLink]:
    from lattice_checks import SIM_TIMEOUT

    from membrane_coppelia.link import connect_simulator

    connection = connect_simulator("127.0.0.1", standin.port, SIM_TIMEOUT)
    yield connection
    connection.close()


@pytest.fixture
def membrane_client(membrane_server: Any) -> Iterator[Client]:  # noqa: F811 (the fixture)
    with Client(membrane_server.address, timeout=5.0) as client:
        yield client
