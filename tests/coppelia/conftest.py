"""The server's fixtures (tests/helpers/server_fixtures.py): the adapter talks to a live server.

Plus the live scenes the probe path presses, one server each for the whole folder (building a
live engine takes a moment; sessions keep the tests apart).
"""

from collections.abc import Iterator

import pytest
from server_fixtures import (  # noqa: F401 (fixtures register by name)
    LOOPBACK_ANY_PORT,
    make_scene,
    membrane_server,
    start_server,
)

from membrane_server.server import Server


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
