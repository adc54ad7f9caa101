"""The bridge (`membrane view`'s aiohttp app) in a thread of its own on a free loopback port:
used by tests/view's conftest.py and by measure_view.py."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable

from aiohttp import web as aiohttp_web

from membrane_view.bridge import BridgeConfig, make_app

__all__ = ["BridgeFactory", "BridgeThread"]


class BridgeThread:
    """`membrane view`'s app served from a background thread.

    ``url`` is its page with the token (add a query with ``&``), ``base`` its address without
    one, ``ws_url`` its WebSocket with the token.
    """

    def __init__(self, config: BridgeConfig):
        self.config = config
        self.loop = asyncio.new_event_loop()
        self.runner = aiohttp_web.AppRunner(make_app(config), shutdown_timeout=1.0)
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self.loop).result(timeout=30)
        host, port = self.runner.addresses[0][:2]
        self.host, self.port = str(host), int(port)
        self.base = f"http://{host}:{port}/"
        self.token = config.token
        self.url = f"{self.base}?token={self.token}"
        self.ws_url = f"ws://{host}:{port}/ws?token={self.token}"

    async def _start(self) -> None:
        await self.runner.setup()
        await aiohttp_web.TCPSite(self.runner, "127.0.0.1", 0).start()

    async def _stop(self) -> None:
        await self.runner.cleanup()
        pending = [task for task in asyncio.all_tasks() if task is not asyncio.current_task()]
        for task in pending:
            task.cancel()
        await asyncio.gather(*pending, return_exceptions=True)

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self._stop(), self.loop).result(timeout=30)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=10)
        self.loop.close()


BridgeFactory = Callable[..., BridgeThread]
