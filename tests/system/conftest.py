"""The server's fixtures (tests/helpers/server_fixtures.py) that the end-to-end tests use, and
the attack modules' servers in child processes (``watched``)."""

from collections.abc import Iterator

import pytest
from attackers import WatchedServer
from server_fixtures import (  # noqa: F401 (fixtures register by name)
    evaluator_scenes,
    make_scene,
    membrane_server,
    start_server,
    test_models,
)


@pytest.fixture
def watched() -> Iterator[list[WatchedServer]]:
    """Servers a test starts (``WatchedServer``: `membrane serve` in a child process); killed
    at teardown."""
    started: list[WatchedServer] = []
    yield started
    for server in started:
        server.close()
