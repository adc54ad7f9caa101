"""The bridge against a real server: the page and its modules, the WebSocket's frames (their
bytes), a pointer press on a live scene, and an unreachable server reported to the page."""

from __future__ import annotations

import asyncio
import json
import struct
from typing import Any

import aiohttp
import numpy as np
import pytest
from view_fixtures import BridgeFactory

from membrane_client.client import Client
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.server import Server
from membrane_view.wire import (
    FLAG_CONTACT,
    FLAG_LIVE,
    HEADER_SIZE,
    WireFrame,
    decode_frame,
    encode_frame,
)


def test_a_frame_is_a_32_byte_header_and_little_endian_float32() -> None:
    z = np.arange(6, dtype=np.float64).reshape(2, 3) / 7
    data = encode_frame(5, 0.25, z, force=1.5, bridge_us=12.0, flags=FLAG_LIVE | FLAG_CONTACT)
    assert HEADER_SIZE == 32 and len(data) == 32 + 6 * 4
    assert data[:4] == b"MBF1"
    assert struct.unpack_from("<I", data, 4)[0] == 5
    assert struct.unpack_from("<d", data, 8)[0] == 0.25
    assert struct.unpack_from("<f", data, 16)[0] == 1.5
    assert struct.unpack_from("<I", data, 20)[0] == 6
    assert struct.unpack_from("<I", data, 28)[0] == 3
    assert data[32:] == z.astype("<f4").tobytes()
    frame = decode_frame(data)
    assert (frame.k, frame.t, frame.force, frame.flags) == (5, 0.25, 1.5, 3)
    np.testing.assert_array_equal(frame.z, z.astype(np.float32).ravel())
    for bad in (data[:31], b"XXXX" + data[4:], data + b"\0\0\0\0"):
        with pytest.raises(ValueError):
            decode_frame(bad)


async def _collect(
    ws_url: str,
    frames: int,
    *,
    send: list[dict[str, Any]] | None = None,
    until: Any = None,
    limit_s: float = 20.0,
    for_s: float | None = None,
) -> tuple[list[dict[str, Any]], list[WireFrame]]:
    """Open the WebSocket, send ``send`` once the scene message has come, collect JSON
    messages and ``frames`` binary frames (or until ``until(frame)``), or all that come in
    ``for_s`` seconds."""
    texts: list[dict[str, Any]] = []
    got: list[WireFrame] = []
    async with aiohttp.ClientSession() as http, http.ws_connect(ws_url) as ws:
        try:
            async with asyncio.timeout(for_s or limit_s):
                async for message in ws:
                    if message.type == aiohttp.WSMsgType.TEXT:
                        texts.append(json.loads(message.data))
                        if texts[-1]["type"] == "scene":
                            for outgoing in send or []:
                                await ws.send_str(json.dumps(outgoing))
                    elif message.type == aiohttp.WSMsgType.BINARY:
                        got.append(decode_frame(message.data))
                        if for_s is None and (until(got[-1]) if until else len(got) >= frames):
                            break
        except TimeoutError:
            if for_s is None:
                raise
    return texts, got


def test_the_page_and_its_modules_are_served(
    membrane_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(membrane_server.address, scene="membrane")

    async def fetch() -> dict[str, tuple[int, str, str]]:
        out = {}
        async with aiohttp.ClientSession() as http:
            for path in ("static/view.js", "static/render2d.js", "static/wire.js", "nope"):
                async with http.get(bridge.base + path) as reply:
                    out[path] = (reply.status, reply.content_type, await reply.text())
            async with http.get(bridge.url) as reply:
                out[""] = (reply.status, reply.content_type, await reply.text())
        return out

    pages = asyncio.run(fetch())
    assert pages[""][0] == 200 and '<canvas id="surface"' in pages[""][2]
    assert pages["static/view.js"][0] == 200 and "javascript" in pages["static/view.js"][1]
    assert "decodeFrame" in pages["static/wire.js"][2]
    assert pages["nope"][0] == 404


def test_a_film_scene_streams_the_servers_frames_bit_for_bit(
    membrane_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(membrane_server.address, scene="membrane", speed=0.5)
    texts, frames = asyncio.run(_collect(bridge.ws_url, 12))
    scene = next(t for t in texts if t["type"] == "scene")
    assert scene["shape"] == [20, 20] and scene["live"] is False and scene["dt"] == 0.01
    assert [f.k for f in frames] == sorted(f.k for f in frames)
    assert frames[-1].k > frames[0].k  # the film plays
    with Client(membrane_server.address) as client:
        for frame in frames[-3:]:
            assert frame.flags == 0 and np.isnan(frame.force)
            expected = client.query(frame.t, "membrane").z
            assert frame.z.tobytes() == np.asarray(expected, dtype="<f4").tobytes()


def test_a_press_on_a_live_scene_gives_a_force_and_a_dent(
    live_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(live_server.address, scene="membrane-live")
    _, before = asyncio.run(_collect(bridge.ws_url, 5))
    assert all(f.flags & FLAG_LIVE and f.force == 0.0 for f in before)
    press = {"type": "press", "at": [0.5, 0.5], "depth": 0.01, "radius": 0.05}
    texts, frames = asyncio.run(
        _collect(bridge.ws_url, 0, send=[press], until=lambda f: f.force > 0 and f.z.min() < -0.005)
    )
    last = frames[-1]
    assert last.force > 0 and last.flags & FLAG_CONTACT
    dent = last.z.reshape(20, 20)
    assert dent[10, 10] < -0.005 and dent[10, 10] < dent[0, 0]
    assert any(t["type"] == "scene" and t["live"] for t in texts)


@pytest.mark.slow
def test_stats_reach_the_page_with_the_bridges_own_time(
    live_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(live_server.address, scene="rope-live")
    texts, _ = asyncio.run(_collect(bridge.ws_url, 0, for_s=2.5))
    stats = [t for t in texts if t["type"] == "stats"]
    assert stats, texts
    last = stats[-1]
    assert last["server"]["requests"] > 0 and last["server"]["live_steps"] > 0
    assert last["bridge"]["frames"] > 0 and "p99" in last["bridge"]["bridge_us"]


def test_an_unreachable_server_is_an_error_on_the_page(start_bridge: BridgeFactory) -> None:
    bridge = start_bridge("tcp://127.0.0.1:9", timeout=0.2)

    async def first_error() -> dict[str, Any]:
        async with aiohttp.ClientSession() as http, http.ws_connect(bridge.ws_url) as ws:
            async with asyncio.timeout(10):
                while True:
                    message = json.loads(await ws.receive_str())
                    if message["type"] == "error":
                        return message

    error = asyncio.run(first_error())
    assert "server unreachable at tcp://127.0.0.1:9" in error["message"]


@pytest.mark.slow
def test_a_lost_session_is_shown_and_a_new_one_opened(
    live_server: Server, start_bridge: BridgeFactory
) -> None:
    from membrane_client.session import Session

    bridge = start_bridge(live_server.address, scene="membrane-live")

    def end_every_session() -> None:
        """As an expiry would: the sessions are closed on the server, behind the bridge."""
        with Client(live_server.address) as client:
            for session_id in list(live_server.sessions._sessions):
                Session(client, "membrane-live", session_id).close()

    async def run() -> tuple[str, list[WireFrame]]:
        after: list[WireFrame] = []
        error, ended = "", False
        async with aiohttp.ClientSession() as http, http.ws_connect(bridge.ws_url) as ws:
            async with asyncio.timeout(20):
                while len(after) < 5:
                    message = await ws.receive()
                    if message.type == aiohttp.WSMsgType.BINARY:
                        frame = decode_frame(message.data)
                        if error:
                            after.append(frame)
                        elif frame.k > 300 and not ended:
                            ended = True
                            await asyncio.to_thread(end_every_session)
                    elif message.type == aiohttp.WSMsgType.TEXT:
                        text = json.loads(message.data)
                        if text["type"] == "error":
                            error = text["message"]
        return error, after

    error, after = asyncio.run(run())
    assert "session lost" in error and "no open session" in error, error
    assert after[0].k < 300 and after[-1].k > after[0].k  # a new session, stepping again


def test_the_scene_message_carries_a_point_lists_points_and_no_grids() -> None:
    from membrane_server.scene import scene_from_dict
    from membrane_server.served import ServedScene
    from membrane_view.bridge import BridgeConfig, scene_message

    listed = scene_from_dict(
        {"name": "few", "model": "membrane-forced", "evaluator": "exact",
         "lattice": {"points": [[0.1, 0.2], [0.9, 0.4], [0.5, 0.5]]}, "dt": 0.01, "duration": 1.0}
    )  # fmt: skip
    grid = scene_from_dict(
        {"name": "grid", "model": "membrane-forced", "evaluator": "exact",
         "lattice": {"nx": 4, "ny": 3}, "dt": 0.01, "duration": 1.0}
    )  # fmt: skip
    config = BridgeConfig(connect="tcp://127.0.0.1:9")
    for scene, points in ((listed, [[0.1, 0.2], [0.9, 0.4], [0.5, 0.5]]), (grid, None)):
        served = ServedScene.load(scene)
        with Client("in-process://", transport=InProcessTransport(Dispatcher([served]))) as c:
            message = scene_message(c.describe(), config)
        assert message["points"] == points
        json.dumps(message)  # the page gets it as JSON


@pytest.mark.parametrize(
    ("tool", "felt"),
    [("sphere", lambda f: f.force > 0), ("cylinder", lambda f: f.force > 0), ("grasp", None)],
)
def test_a_press_with_a_rigid_tool_or_a_grasp_reaches_the_tissue(
    live_server: Server, start_bridge: BridgeFactory, tool: str, felt: Any
) -> None:
    """A sphere or a cylinder presses a dent and feels a contact force; a grasp lifts the
    tissue at its point (the frame's peak above rest) and holds it with a force."""
    bridge = start_bridge(live_server.address, scene="membrane-live")
    # The page's tool radius (10 % of the side): the lattice points nearest the centre are
    # 0.037 off it, where a 0.05 sphere 0.01 deep would not reach the rest surface.
    press = {"type": "press", "at": [0.5, 0.5], "depth": 0.02, "radius": 0.1, "tool": tool}
    if tool == "grasp":
        until = lambda f: f.z.reshape(20, 20)[10, 10] > 0.01 and f.force != 0.0  # noqa: E731
    else:
        until = lambda f: felt(f) and f.z.min() < -0.005  # noqa: E731
    texts, frames = asyncio.run(_collect(bridge.ws_url, 0, send=[press], until=until))
    assert frames[-1].flags & FLAG_CONTACT
    scene = next(t for t in texts if t["type"] == "scene")
    assert scene["tools"] == ["tip", "sphere", "cylinder", "grasp"]


@pytest.mark.slow  # builds skin-disk's FEM tables (about 13 s)
def test_the_scene_message_says_units_tools_and_a_physical_scenes_triangles(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    from membrane_server.served import ServedScene
    from membrane_view.bridge import BridgeConfig, scene_message

    monkeypatch.setenv("MEMBRANE_CACHE_DIR", str(tmp_path))
    config = BridgeConfig(connect="tcp://127.0.0.1:9")
    served = [ServedScene.load(name) for name in ("membrane-live", "skin-disk")]
    with Client("in-process://", transport=InProcessTransport(Dispatcher(served))) as c:
        live, disk = (scene_message(c.describe(n), config) for n in ("membrane-live", "skin-disk"))
    assert live["units"] == {
        "length": "problem units", "factor": 1.0, "force": "problem units", "physical": False,
    }  # fmt: skip
    assert live["triangles"] is None and live["depth_max"] == pytest.approx(0.02)
    assert disk["units"]["length"] == "mm" and disk["units"]["force"] == "N"
    assert disk["depth_max"] == pytest.approx(0.004)  # 10 % of the 40 mm disk
    assert disk["radius"] == 0.0  # the plate's tables carry point forces only
    assert disk["tools"] == ["tip", "sphere", "cylinder", "grasp"]
    triangles = np.asarray(disk["triangles"]).reshape(-1, 3)
    corners = served[1].evaluator.points[triangles]  # (m, 3, 2) m
    assert 0 < len(triangles) < 2 * 16 * 16  # the disk's inside only, of the grid's cells
    assert np.linalg.norm(corners - 0.02, axis=2).max() <= 0.02 + 1e-12
    json.dumps(disk)
