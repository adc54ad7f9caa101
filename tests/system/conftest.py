"""The server's fixtures (tests/helpers/server_fixtures.py) that the end-to-end tests use."""

from server_fixtures import (  # noqa: F401 (fixtures register by name)
    evaluator_scenes,
    make_scene,
    membrane_server,
    start_server,
    test_models,
)
