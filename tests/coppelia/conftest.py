"""The server's fixtures (tests/helpers/server_fixtures.py): the adapter talks to a live server."""

from server_fixtures import (  # noqa: F401 (fixtures register by name)
    make_scene,
    membrane_server,
    start_server,
)
