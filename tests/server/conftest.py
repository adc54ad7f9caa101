"""The server's fixtures (tests/helpers/server_fixtures.py): test models, scenes, live servers;
and the FEM caches of physical scenes."""

from collections.abc import Iterator
from pathlib import Path

import pytest
from server_fixtures import (  # noqa: F401 (fixtures register by name)
    evaluator_scenes,
    evaluator_server,
    make_scene,
    many_sessions_server,
    membrane_server,
    start_server,
    test_models,
)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The FEM caches in a temporary directory, one per module (never the user's)."""
    with pytest.MonkeyPatch.context() as patch:
        path = tmp_path_factory.mktemp("fem-cache")
        patch.setenv("MEMBRANE_CACHE_DIR", str(path))
        yield path
