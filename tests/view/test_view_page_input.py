"""What the page sends: each bad message (wrong coordinate counts, radii below the scene's
min_radius or absurd, `depth: true`, depths past the slider, deep nesting, unknown types) is
answered with one short error, and the connection, the session and the pointer are kept: no
reconnection, no new session, no force."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import aiohttp
import pytest
from view_fixtures import BridgeFactory

from membrane_client.live_limits import LiveLimits
from membrane_server.server import Server
from membrane_view.page_input import (
    MAX_ERROR_CHARS,
    MAX_MESSAGE_CHARS,
    PageInputError,
    error_message,
    nesting_exceeds,
    parse_page_message,
)
from membrane_view.wire import decode_frame

LIMITS = LiveLimits(2, min_radius=0.00390625)  # membrane-live's
GOOD = {"type": "press", "at": [0.5, 0.5], "depth": 0.01, "radius": 0.05}


def _press(**fields: Any) -> str:
    return json.dumps({**GOOD, **fields})


# Defect 9's messages, and more of the same kind: (text, what the error says).
BAD: list[tuple[str, str]] = [
    (_press(at=[0.5]), "probe at must be 2 numbers, got 1 value"),
    (_press(at=[0.5, 0.5, 0.5]), "got 3 values"),
    (_press(at=[0.5] * 7000), "at most 4096 characters"),
    (_press(at=[0.1] * 500), "got 500 values"),
    (_press(radius=1e-4), "got 0.0001"),
    (_press(radius=0.0039), "probe radius must be in ["),
    (_press(radius=1e308), "got 1e+308"),
    (_press(radius=1e-310), "got 1e-310"),
    (_press(depth=True), "probe depth must be a number, got a bool"),
    (_press(depth=1.0), "probe depth must be in [0, 0.02], got 1"),
    (_press(depth=0.0201), "in [0, 0.02]"),
    (_press(depth=-0.01), "in [0, 0.02]"),
    (_press(depth="0.01"), "got a string '0.01'"),
    (_press(at=[0.5, "x" * 3000]), "x" * 64 + "'..."),
    ('{"type": "press", "at": [0.5, NaN], "depth": 0.01, "radius": 0.05}', "must be finite"),
    ('{"type": "press", "at": [0.5, 1e999], "depth": 0.01, "radius": 0.05}', "must be finite"),
    ('{"type": "press", "at": [0.5, 0.5], "depth": 0.01}', "missing ['radius']"),
    (_press(extra=1), "1 other"),
    ("[" * 2000 + "]" * 2000, "nests at most 4 levels"),
    ('{"type": "press", "at": [[[[[0.5]]]]], "depth": 0.01, "radius": 0.05}', "nests at most"),
    ("not json", "not JSON"),
    ('{"type": "press"', "not JSON"),
    ("[1, 2]", "a message is a JSON object, got an array of 2"),
    ('"press"', "got 'press'"),
    ('{"type": "what"}', "unknown type 'what'"),
    ('{"type": ["press"]}', "unknown type an array of 1"),
    ('{"at": [0.5, 0.5]}', "unknown type null"),
    ('{"type": "release", "at": [0.5, 0.5]}', "release takes no fields besides type"),
]


@pytest.mark.parametrize(("text", "says"), BAD)
def test_a_bad_message_is_refused_with_a_short_line(text: str, says: str) -> None:
    with pytest.raises(PageInputError) as caught:
        parse_page_message(text, LIMITS, max_depth=0.02)
    message = error_message(f"page message refused: {caught.value}", source="page")
    assert says in message["message"], message
    assert len(message["message"]) <= MAX_ERROR_CHARS and "\n" not in message["message"]


def test_good_messages_and_a_press_on_a_film() -> None:
    press = parse_page_message(json.dumps(GOOD), LIMITS, max_depth=0.02)
    assert press.kind == "press" and press.probe == ((0.5, 0.5), 0.01, 0.05)
    assert parse_page_message('{"type": "release"}', LIMITS, 0.02).kind == "release"
    assert parse_page_message('{"type": "reset"}', None, 0.02).kind == "reset"
    with pytest.raises(PageInputError, match="needs a live scene"):
        parse_page_message(json.dumps(GOOD), None, 0.02)
    # Brackets inside a string are not nesting.
    with pytest.raises(PageInputError, match="unknown type"):
        parse_page_message(json.dumps({"type": "[" * 1000}), LIMITS, 0.02)


def test_nesting_is_measured_without_recursion() -> None:
    assert not nesting_exceeds('{"at": [1, 2]}', 2)
    assert nesting_exceeds('{"at": [[1]]}', 2)
    assert not nesting_exceeds('["[[[[", "\\"[[["]', 1)
    assert nesting_exceeds("[" * 1_000_000, 32)  # far past the recursion limit: no error
    assert len("[" * MAX_MESSAGE_CHARS) == MAX_MESSAGE_CHARS
    with pytest.raises(PageInputError, match="nests"):  # json.loads would raise RecursionError
        parse_page_message("[" * MAX_MESSAGE_CHARS, LIMITS, 0.02)
    assert error_message("x" * 1000)["message"].endswith("...")
    assert len(error_message("x" * 1000)["message"]) == MAX_ERROR_CHARS


async def _wait_scene(ws: aiohttp.ClientWebSocketResponse) -> dict[str, Any]:
    async with asyncio.timeout(20):
        while True:
            message = await ws.receive()
            if message.type == aiohttp.WSMsgType.TEXT:
                text = json.loads(message.data)
                if text["type"] == "scene":
                    return text


async def _send_and_read(
    ws: aiohttp.ClientWebSocketResponse, texts: list[str], binary: bool = False
) -> tuple[list[dict[str, Any]], list[float], int]:
    """Send ``texts`` (and one binary message); read until an error per message has come and
    some frames after; the JSON messages, the frames' forces, their last k."""
    for text in texts:
        await ws.send_str(text)
    if binary:
        await ws.send_bytes(b"\x00\x01")
    expected = len(texts) + binary
    got: list[dict[str, Any]] = []
    forces: list[float] = []
    last_k = -1
    async with asyncio.timeout(30):
        while sum(m["type"] == "error" for m in got) < expected or len(forces) < 10:
            message = await ws.receive()
            assert message.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.BINARY), message
            if message.type == aiohttp.WSMsgType.TEXT:
                got.append(json.loads(message.data))
            else:
                frame = decode_frame(message.data)
                forces.append(frame.force)
                last_k = frame.k
    return got, forces, last_k


def test_bad_page_messages_are_answered_and_the_session_kept(
    start_server: Any, start_bridge: BridgeFactory
) -> None:
    server: Server = start_server(["membrane-live"])
    bridge = start_bridge(server.address, scene="membrane-live")
    texts = [text for text, _ in BAD]

    async def run() -> tuple[list[dict[str, Any]], list[float], list[int], bool, list[float]]:
        sessions: list[int] = []
        async with aiohttp.ClientSession() as http, http.ws_connect(bridge.ws_url) as ws:
            scene = await _wait_scene(ws)
            assert scene["depth_max"] == pytest.approx(0.02)
            sessions.append(len(server.sessions))
            got, forces, k0 = await _send_and_read(ws, texts, binary=True)
            sessions.append(len(server.sessions))
            flood, _, k1 = await _send_and_read(ws, ['{"type": "what"}'] * 500)
            assert sum(m["type"] == "error" for m in flood) >= 500 and k1 > k0
            await ws.send_str(json.dumps(GOOD))  # the same session still takes a good press
            pressed: list[float] = []
            async with asyncio.timeout(20):
                while not pressed or pressed[-1] <= 0:
                    message = await ws.receive()
                    if message.type == aiohttp.WSMsgType.BINARY:
                        pressed.append(decode_frame(message.data).force)
            sessions.append(len(server.sessions))
            return got, forces, sessions, ws.closed, pressed

    got, forces, sessions, closed, pressed = asyncio.run(run())
    errors = [m for m in got if m["type"] == "error"]
    assert len(errors) == len(BAD) + 1, errors
    for message, (_, says) in zip(errors, BAD, strict=False):
        assert message["source"] == "page" and says in message["message"], (says, message)
        assert message["message"].startswith("page message refused: ")
        assert len(message["message"]) <= MAX_ERROR_CHARS
    assert "JSON text, not binary" in errors[-1]["message"]
    assert not [m for m in got if m["type"] == "scene"], "the bridge reconnected"
    assert all(force == 0.0 for force in forces), "a refused press reached the tissue"
    assert sessions == [1, 1, 1] and not closed
    assert pressed[-1] > 0


def test_a_press_the_server_refuses_keeps_the_session(
    start_server: Any, start_bridge: BridgeFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Defence in depth: were the bridge's bounds looser than the server's, the refused step is
    reported to the page and the press dropped, but the session is not reopened."""
    import membrane_view.bridge as bridge_module

    lax = LiveLimits(2, min_radius=0.0)
    monkeypatch.setattr(bridge_module.LiveLimits, "from_live", classmethod(lambda *_: lax))
    server: Server = start_server(["membrane-live"])
    bridge = start_bridge(server.address, scene="membrane-live")

    async def run() -> tuple[list[dict[str, Any]], list[float], int, list[int]]:
        async with aiohttp.ClientSession() as http, http.ws_connect(bridge.ws_url) as ws:
            await _wait_scene(ws)
            await ws.send_str(_press(radius=1e-4))
            got, forces, k = await _send_and_read(ws, [])
            async with asyncio.timeout(20):
                while not any(m["type"] == "error" for m in got):
                    message = await ws.receive()
                    if message.type == aiohttp.WSMsgType.TEXT:
                        got.append(json.loads(message.data))
            after, more, k2 = await _send_and_read(ws, [])
            return got + after, forces + more, len(server.sessions), [k, k2]

    got, forces, sessions, ks = asyncio.run(run())
    errors = [m for m in got if m["type"] == "error"]
    assert errors and "the server refused the press" in errors[0]["message"], got
    assert errors[0]["source"] == "page" and len(errors[0]["message"]) <= MAX_ERROR_CHARS
    assert not [m for m in got if m["type"] == "scene"], "the bridge reconnected"
    assert sessions == 1 and ks[1] > ks[0] and all(f == 0.0 for f in forces)


ALL_TOOLS = ("tip", "sphere", "cylinder", "grasp")


@pytest.mark.parametrize("tool", ALL_TOOLS)
def test_a_press_names_the_tool_it_presses_with(tool: str) -> None:
    press = parse_page_message(_press(tool=tool), LIMITS, max_depth=0.02, tools=ALL_TOOLS)
    assert press.tool == tool and press.probe == ((0.5, 0.5), 0.01, 0.05)


@pytest.mark.parametrize(
    ("fields", "tools", "says"),
    [
        ({"tool": "scalpel"}, ALL_TOOLS, "tool 'scalpel': this scene takes tip, sphere"),
        ({"tool": ["sphere"]}, ALL_TOOLS, "tool an array of 1"),
        ({"tool": "grasp"}, ("sphere", "cylinder"), "this scene takes sphere, cylinder"),
        ({"tool": "sphere", "radius": 0.0}, ALL_TOOLS, "radius must be > 0"),
        ({"tool": "sphere", "depth": 0.03}, ALL_TOOLS, "in [0, 0.02]"),
    ],
)
def test_a_tool_the_scene_does_not_take_is_refused(
    fields: dict[str, Any], tools: tuple[str, ...], says: str
) -> None:
    lax = LiveLimits(2, min_radius=0.0, point_forces=True)
    with pytest.raises(PageInputError, match=None) as caught:
        parse_page_message(_press(**fields), lax, max_depth=0.02, tools=tools)
    assert says in str(caught.value), caught.value


def test_a_press_without_a_tool_is_the_soft_tip() -> None:
    assert parse_page_message(json.dumps(GOOD), LIMITS, max_depth=0.02).tool == "tip"
