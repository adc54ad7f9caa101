"""Fixtures that need the server: tiny ONNX models, scenes built on them, servers on loopback.

The conftest.py of each folder whose tests use them (tests/server, tests/system, tests/coppelia)
imports them by name; tests/client has none, so that it runs on a client-only install. Each of
those folders gets its own instances of the session-wide fixtures.

Servers bind ``tcp://127.0.0.1:*`` (a free port), run in a background thread of the test process,
and are stopped (sockets closed, LINGER 0) at teardown.

- ``test_models``: untrained separable graphs following the manifest contract (onnx_graphs.py):
  ``membrane`` (2-D, separable), ``string`` (1-D, separable), ``membrane_full_only`` (2-D, full
  graph only).
- ``make_scene(model, evaluator, **fields)``: a validated Scene (20 x 20 by default for 2-D).
- ``start_server(scenes, **kwargs)``: a started Server; stopped at teardown.
- ``evaluator_server``: one server (session-wide) hosting scenes named ``network``,
  ``separable``, ``table`` (the 2-D test model) and ``exact`` (the membrane-forced problem),
  all 20 x 20, dt 0.01, duration 1 s, policy hold.
- ``membrane_server``: a server (session-wide) on the built-in ``membrane`` scene.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from onnx_graphs import TestModel, build_test_model

from membrane_server.scene import Scene, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.server import Server
from membrane_server.sessions import SessionTable

LOOPBACK_ANY_PORT = "tcp://127.0.0.1:*"

SceneFactory = Callable[..., Scene]
ServerFactory = Callable[..., Server]


@pytest.fixture(scope="session")
def test_models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, TestModel]:
    """Small untrained ONNX models on disk, by name."""
    directory = tmp_path_factory.mktemp("models")
    return {
        "membrane": build_test_model(directory, "membrane-test", spatial_dims=2, rank=8, seed=1),
        "string": build_test_model(directory, "string-test", spatial_dims=1, rank=6, seed=2),
        "membrane_full_only": build_test_model(
            directory, "membrane-full-only", spatial_dims=2, rank=8, seed=3, separable=False
        ),
    }


def _scene(model: str | Path, evaluator: str, **fields: Any) -> Scene:
    data: dict[str, Any] = {
        "name": evaluator,
        "model": str(model),
        "evaluator": evaluator,
        "lattice": {"nx": 20, "ny": 20},
        "dt": 0.01,
        "duration": 1.0,
        "policy": "hold",
    }
    data.update(fields)
    return scene_from_dict(data)


@pytest.fixture(scope="session")
def make_scene() -> SceneFactory:
    """Build a Scene: ``make_scene(model_path_or_name, evaluator, **fields)``."""
    return _scene


@pytest.fixture
def start_server() -> Iterator[ServerFactory]:
    """Start servers in background threads on free loopback ports; all stopped at teardown."""
    started: list[Server] = []

    def start(scenes: list[Any], **kwargs: Any) -> Server:
        server = Server(scenes, bind=kwargs.pop("bind", LOOPBACK_ANY_PORT), **kwargs)
        server.start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


@pytest.fixture(scope="session")
def evaluator_scenes(test_models: dict[str, TestModel]) -> dict[str, ServedScene]:
    """The four evaluators on a 20 x 20 lattice, built once, by evaluator kind."""
    model = test_models["membrane"].manifest_path
    scenes = [_scene(model, kind) for kind in ("network", "separable", "table")]
    scenes.append(_scene("membrane-forced", "exact"))
    return {scene.name: ServedScene.load(scene) for scene in scenes}


@pytest.fixture(scope="session")
def evaluator_server(evaluator_scenes: dict[str, ServedScene]) -> Iterator[Server]:
    """One server hosting scenes 'network', 'separable', 'table' and 'exact'."""
    server = Server(list(evaluator_scenes.values()), bind=LOOPBACK_ANY_PORT)
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="session")
def membrane_server() -> Iterator[Server]:
    """A server on the built-in 'membrane' scene."""
    server = Server(["membrane"], bind=LOOPBACK_ANY_PORT)
    server.start()
    yield server
    server.stop()


@pytest.fixture
def many_sessions_server() -> Iterator[Server]:
    """A server on `membrane-live` that holds 300 sessions, all of one peer if it likes (a
    client of many environments)."""
    sessions = SessionTable(300, 60.0, max_per_peer=300)
    server = Server(["membrane-live"], bind=LOOPBACK_ANY_PORT, sessions=sessions)
    server.start()
    yield server
    server.stop()
