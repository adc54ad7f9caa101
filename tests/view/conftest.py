"""The view's fixtures: servers on loopback (tests/helpers/server_fixtures.py), and the bridge
(an aiohttp app) in a thread of its own on a free loopback port (view_fixtures.py)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from server_fixtures import (  # noqa: F401 (fixtures register by name)
    LOOPBACK_ANY_PORT,
    membrane_server,
    start_server,
)

from membrane_server.server import Server

pytest.importorskip("aiohttp", reason="the 'view' extra (aiohttp) is missing")

from view_fixtures import BridgeFactory, BridgeThread

from membrane_view.bridge import BridgeConfig


@pytest.fixture
def start_bridge() -> Iterator[BridgeFactory]:
    """``start_bridge(connect, scene=..., **config)``: a running bridge, stopped at teardown."""
    started: list[BridgeThread] = []

    def start(connect: str, **fields: object) -> BridgeThread:
        bridge = BridgeThread(BridgeConfig(connect=connect, **fields))  # type: ignore[arg-type]
        started.append(bridge)
        return bridge

    yield start
    for bridge in started:
        bridge.stop()


@pytest.fixture(scope="session")
def live_server() -> Iterator[Server]:
    """A server on the built-in live scenes 'membrane-live' and 'rope-live'."""
    server = Server(["membrane-live", "rope-live"], bind=LOOPBACK_ANY_PORT)
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def skin_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server on the physical 'skin-patch' (SI units), its FEM tables built in a temporary
    cache (never the user's)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MEMBRANE_CACHE_DIR", str(tmp_path_factory.mktemp("fem-cache")))
        server = Server(["skin-patch"], bind=LOOPBACK_ANY_PORT)
        server.start()
        yield server
        server.stop()
