"""The server's fixtures (tests/helpers/server_fixtures.py): test models, scenes, live servers."""

from server_fixtures import (  # noqa: F401 (fixtures register by name)
    evaluator_scenes,
    evaluator_server,
    make_scene,
    membrane_server,
    start_server,
    test_models,
)
