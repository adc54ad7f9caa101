"""Who may talk to the bridge: a foreign Host (DNS rebinding) or Origin gets 403, the page and
the WebSocket need the start-up token, and WebSockets past --max-connections get 503 while the
bridge's threads stay a fixed few (docs/VIEW.md, "Who may connect")."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from typing import Any

import aiohttp
import pytest
from view_fixtures import BridgeFactory, BridgeThread

from membrane_server.server import Server
from membrane_view.guard import own_hosts, token_matches

HANDSHAKE = (
    "GET {path} HTTP/1.1\r\nHost: {host}\r\n{extra}Upgrade: websocket\r\nConnection: Upgrade\r\n"
    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
)


async def _raw(port: int, request: str) -> tuple[int, str]:
    """One raw HTTP request (any Host header); the status and the start of the body."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request.encode())
        await writer.drain()
        async with asyncio.timeout(10):
            head = await reader.readuntil(b"\r\n\r\n")
            body = b"" if b" 101 " in head[:16] else await reader.read(400)
    finally:
        writer.close()
    return int(head.split()[1]), body.decode(errors="replace")


def _get(path: str, host: str, extra: str = "") -> str:
    return f"GET {path} HTTP/1.1\r\nHost: {host}\r\n{extra}Connection: close\r\n\r\n"


def test_a_foreign_host_gets_403_so_dns_rebinding_fails(
    membrane_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(membrane_server.address, scene="membrane")
    port, page = bridge.port, f"/?token={bridge.token}"
    ws = f"/ws?token={bridge.token}"

    async def run() -> dict[str, tuple[int, str]]:
        asks = {
            "own page": _get(page, f"127.0.0.1:{port}"),
            "localhost": _get(page, f"LocalHost:{port}"),
            "rebound page": _get(page, f"evil.example:{port}"),
            "rebound module": _get("/static/view.js", f"evil.example:{port}"),
            "other port": _get(page, f"127.0.0.1:{port + 1}"),
            "no port": _get(page, "127.0.0.1"),
            "two hosts": _get(page, f"127.0.0.1:{port}\r\nHost: evil.example:{port}"),
            "rebound socket": HANDSHAKE.format(path=ws, host=f"evil.example:{port}", extra=""),
            "own socket": HANDSHAKE.format(path=ws, host=f"127.0.0.1:{port}", extra=""),
        }
        return {name: await _raw(port, text) for name, text in asks.items()}

    got = asyncio.run(run())
    assert got["own page"][0] == 200 and got["localhost"][0] == 200
    assert got["own socket"][0] == 101
    for name in ("rebound page", "rebound module", "other port", "no port", "rebound socket"):
        status, body = got[name]
        assert status == 403 and "Host is not this bridge's address" in body, (name, got[name])
        assert "evil" not in body  # nothing of the request is echoed
    assert got["two hosts"][0] in (400, 403)  # aiohttp may refuse it before the guard


def test_the_page_and_the_websocket_need_the_token(
    membrane_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(membrane_server.address, scene="membrane")
    wrong = bridge.token[:-1] + ("A" if bridge.token[-1] != "A" else "B")

    async def run() -> dict[str, Any]:
        out: dict[str, Any] = {}
        async with aiohttp.ClientSession() as http:
            for name, url in (
                ("page", bridge.url),
                ("page without", bridge.base),
                ("page wrong", f"{bridge.base}?token={wrong}"),
            ):
                async with http.get(url) as reply:
                    out[name] = (reply.status, await reply.text(), dict(reply.headers))
            for name, url in (
                ("socket without", bridge.base + "ws"),
                ("socket wrong", f"{bridge.base}ws?token={wrong}"),
                ("socket empty", f"{bridge.base}ws?token="),
                ("socket long", f"{bridge.base}ws?token={bridge.token * 50}"),
            ):
                try:
                    async with http.ws_connect(url):
                        out[name] = 101
                except aiohttp.WSServerHandshakeError as exc:
                    out[name] = exc.status
            async with http.ws_connect(bridge.ws_url) as ws:
                out["socket"] = json.loads(await ws.receive_str(timeout=10))["type"]
        return out

    got = asyncio.run(run())
    assert got["page"][0] == 200
    headers = got["page"][2]
    assert "frame-ancestors 'none'" in headers["Content-Security-Policy"]
    assert headers["Referrer-Policy"] == "no-referrer" and headers["Cache-Control"] == "no-store"
    for name in ("page without", "page wrong"):
        assert got[name][0] == 403 and "?token=" in got[name][1], got[name]
    for name in ("socket without", "socket wrong", "socket empty", "socket long"):
        assert got[name] == 403, (name, got[name])
    assert got["socket"] in ("scene", "status")


def test_only_the_bridges_own_origin_may_open_the_websocket(
    membrane_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(membrane_server.address, scene="membrane")
    port = bridge.port

    async def status(origin: str) -> int:
        path, host = f"/ws?token={bridge.token}", f"127.0.0.1:{port}"
        request = HANDSHAKE.format(path=path, host=host, extra=f"Origin: {origin}\r\n")
        return (await _raw(port, request))[0]

    async def run() -> dict[str, int]:
        origins = [
            f"http://127.0.0.1:{port}",
            f"http://localhost:{port}",
            f"http://127.0.0.1:{port + 1}",
            f"https://127.0.0.1:{port}",
            f"http://evil.example:{port}",
            "null",
            "http://127.0.0.1",
        ]
        return {origin: await status(origin) for origin in origins}

    got = asyncio.run(run())
    assert got[f"http://127.0.0.1:{port}"] == 101 and got[f"http://localhost:{port}"] == 101
    refused = [origin for origin, code in got.items() if code == 403]
    assert len(refused) == 5, got


def test_own_hosts_and_the_token_compare() -> None:
    hosts = own_hosts(("127.0.0.1", 8765))
    assert hosts == {"127.0.0.1:8765", "localhost:8765", "[::1]:8765"}
    assert "192.168.1.5:80" in own_hosts(("192.168.1.5", 80))
    assert "192.168.1.5" in own_hosts(("192.168.1.5", 80))  # a browser omits port 80
    assert "[::1]:9000" in own_hosts(("::1", 9000, 0, 0))
    assert own_hosts(None) == frozenset()
    assert token_matches("abc" * 10, "abc" * 10)
    assert not token_matches(None, "abc" * 10) and not token_matches("abc", "abc" * 10)
    assert not token_matches("é" * 30, "abc" * 10)  # not ASCII: refused, no TypeError


def _bridge_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("membrane-view")]


@pytest.mark.slow  # over a second: the full suite runs it
def test_past_the_cap_a_websocket_gets_503_and_opens_nothing(
    start_server: Any, start_bridge: BridgeFactory
) -> None:
    server = start_server(["membrane-live"])
    bridge = start_bridge(server.address, scene="membrane-live", max_connections=2)

    async def run() -> tuple[list[Any], int, str]:
        async with aiohttp.ClientSession() as http:
            first = await http.ws_connect(bridge.ws_url)
            second = await http.ws_connect(bridge.ws_url)
            codes: list[Any] = []
            for _ in range(5):
                try:
                    async with http.ws_connect(bridge.ws_url):
                        codes.append(101)
                except aiohttp.WSServerHandshakeError as exc:
                    codes.append(exc.status)
            async with http.get(bridge.ws_url.replace("ws://", "http://")) as reply:
                text = await reply.text()
            await first.receive(timeout=10)
            await second.receive(timeout=10)
            deadline = time.monotonic() + 10
            while len(server.sessions) < 2 and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            sessions = len(server.sessions)
            await first.close()
            await second.close()
        return codes, sessions, text

    codes, sessions, text = asyncio.run(run())
    assert codes == [503] * 5 and sessions == 2
    assert "at most 2 pages at once (--max-connections)" in text


@pytest.mark.slow
def test_500_connections_are_refused_past_the_cap_and_threads_stay_few(
    start_server: Any, start_bridge: BridgeFactory
) -> None:
    """500 WebSockets asked for at once: --max-connections are served (one session each), the
    rest get 503 and open nothing; the bridge's worker threads stay at most ``workers``."""
    server = start_server(["membrane-live"])
    bridge: BridgeThread = start_bridge(
        server.address, scene="membrane-live", max_connections=8, workers=4
    )
    threads_before = threading.active_count()

    async def run() -> tuple[dict[Any, int], int, int, int]:
        statuses: dict[Any, int] = {}
        held: list[aiohttp.ClientWebSocketResponse] = []
        connector = aiohttp.TCPConnector(limit=0)
        async with aiohttp.ClientSession(connector=connector) as http:

            async def one() -> None:
                try:
                    async with asyncio.timeout(20):
                        held.append(await http.ws_connect(bridge.ws_url))
                    key: Any = 101
                except aiohttp.WSServerHandshakeError as exc:
                    key = exc.status
                statuses[key] = statuses.get(key, 0) + 1

            for _ in range(10):
                await asyncio.gather(*(one() for _ in range(50)))
            deadline = time.monotonic() + 10
            while len(server.sessions) < 8 and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            sessions, threads = len(server.sessions), threading.active_count()
            # The held pages are served: a scene and frames reach each of them.
            firsts = await asyncio.gather(*(ws.receive(timeout=10) for ws in held))
            assert all(m.type == aiohttp.WSMsgType.TEXT for m in firsts), firsts
            for ws in held:
                await ws.close()
            # A closed page frees its place: a new one is served.
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                try:
                    async with http.ws_connect(bridge.ws_url) as ws:
                        await ws.receive(timeout=10)
                        break
                except aiohttp.WSServerHandshakeError:
                    await asyncio.sleep(0.1)
            else:
                raise AssertionError("no place freed after the pages closed")
        return statuses, sessions, threads, len(_bridge_threads())

    statuses, sessions, threads, workers = asyncio.run(run())
    print(f"500 attempts: {statuses}; {sessions} sessions; threads {threads_before} -> {threads}")
    assert statuses == {101: 8, 503: 492}, statuses
    assert sessions == 8
    assert workers <= 4 and threads <= threads_before + 4
