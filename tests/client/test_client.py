"""The thin client: typed errors, Lazy Pirate, clean exit, light imports.

Needs no server: a scripted ROUTER answers as each test says. The client against a real server
(frames and geometry) is tests/server/test_client_with_server.py.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zmq

from membrane_client import (
    Client,
    Frame,
    MembraneError,
    ProtocolError,
    Timeout,
)
from membrane_client.protocol import decode, encode, ok_reply


class ScriptedServer:
    """A ROUTER on loopback that answers each request as a script says (for fault tests).

    ``script(index, request) -> bytes | list[bytes] | None``: the reply payload (several: sent
    one after another on the same connection), or None to stay silent.
    """

    def __init__(self, script: Any) -> None:
        self._socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.ROUTER)
        self._socket.setsockopt(zmq.LINGER, 0)
        port: int = self._socket.bind_to_random_port("tcp://127.0.0.1")
        self.address = f"tcp://127.0.0.1:{port}"
        self.received: list[dict[str, Any]] = []
        self._script = script
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        poller = zmq.Poller()
        poller.register(self._socket, zmq.POLLIN)
        while not self._stop.is_set():
            if not poller.poll(20):
                continue
            identity, empty, payload = self._socket.recv_multipart()
            message = decode(payload)
            reply = self._script(len(self.received), message)
            self.received.append(message)
            for part in [] if reply is None else reply if isinstance(reply, list) else [reply]:
                self._socket.send_multipart([identity, empty, part])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self._socket.close(linger=0)


@pytest.fixture
def scripted() -> Iterator[Any]:
    servers: list[ScriptedServer] = []

    def make(script: Any) -> ScriptedServer:
        servers.append(ScriptedServer(script))
        return servers[-1]

    yield make
    for server in servers:
        server.close()


def pong(message: dict[str, Any]) -> bytes:
    return encode(ok_reply(message["id"], pong=True, time=0.0))


# -- errors -----------------------------------------------------------------------------------


def test_timeout_when_nobody_answers(scripted: Any) -> None:
    server = scripted(lambda index, message: None)
    with Client(server.address, timeout=0.2) as client:
        started = time.monotonic()
        with pytest.raises(Timeout, match="no reply"):
            client.ping()
        assert time.monotonic() - started < 2.0


def test_lazy_pirate_retries_on_a_fresh_socket(scripted: Any) -> None:
    # Silent to the first request, answers the second: one retry recovers.
    server = scripted(lambda index, message: None if index == 0 else pong(message))
    with Client(server.address, timeout=0.2, retries=1) as client:
        assert client.ping() > 0
    assert len(server.received) == 2
    assert server.received[0]["id"] == server.received[1]["id"]  # the same request, re-sent


def test_a_stale_reply_is_never_taken_for_the_answer(scripted: Any) -> None:
    """A relay may deliver a re-sent request's late duplicate reply while the next request
    waits: the client treats it as a lost reply (fresh socket, re-send), never as the answer."""

    def script(index: int, message: dict[str, Any]) -> bytes | list[bytes]:
        if index == 1:  # the second ping: the first ping's twin arrives first
            return [encode(ok_reply(message["id"] - 1, pong=True, time=0.0)), pong(message)]
        return pong(message)

    server = scripted(script)
    with Client(server.address, timeout=1.0, retries=2) as client:
        client.ping()
        client.ping()  # would raise ProtocolError("reply id 1, expected 2") if taken
    assert [m["id"] for m in server.received] == [1, 2, 2]  # the second ping re-sent once


def test_bounded_retries_then_timeout(scripted: Any) -> None:
    server = scripted(lambda index, message: None)
    with Client(server.address, timeout=0.1, retries=2) as client, pytest.raises(Timeout):
        client.ping()
    assert len(server.received) == 3


def test_after_a_timeout_the_next_request_works(scripted: Any) -> None:
    server = scripted(lambda index, message: None if index == 0 else pong(message))
    with Client(server.address, timeout=0.2) as client:
        with pytest.raises(Timeout):
            client.ping()
        assert client.ping() > 0  # a fresh socket: a reused REQ socket would raise EFSM


def test_garbage_reply_is_a_protocol_error(scripted: Any) -> None:
    server = scripted(lambda index, message: b"\xc1\xc1" if index == 0 else pong(message))
    with Client(server.address, timeout=1.0) as client:
        with pytest.raises(ProtocolError):
            client.ping()
        assert client.ping() > 0


def test_reply_to_another_request_is_a_protocol_error(scripted: Any) -> None:
    server = scripted(lambda index, message: encode(ok_reply(message["id"] + 1)))
    with Client(server.address, timeout=1.0) as client, pytest.raises(ProtocolError):
        client.ping()


def test_session_id_is_sent_and_stable(scripted: Any) -> None:
    server = scripted(lambda index, message: None if index == 0 else pong(message))
    with Client(server.address, timeout=0.2, retries=1, session="abc") as client:
        client.ping()
        client.ping()
    assert {m["session"] for m in server.received} == {"abc"}


def test_closed_client_refuses_requests(scripted: Any) -> None:
    client = Client(scripted(lambda index, message: pong(message)).address)
    client.close()
    client.close()  # twice is fine
    assert client.closed
    with pytest.raises(MembraneError, match="closed"):
        client.ping()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"address": "not an endpoint"}, "cannot connect"),
        ({"timeout": 0.0}, "timeout"),
        ({"retries": -1}, "retries"),
    ],
)
def test_bad_arguments_are_value_errors(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Client(**kwargs)


def test_frame_without_info_has_no_positions() -> None:
    frame = Frame(t=0.0, step=0, z=np.zeros(3, np.float32), requested_t=0.0, domain="inside",
                  scene="s")  # fmt: skip
    with pytest.raises(ValueError, match="describe"):
        frame.positions()


# -- process-level behaviour ------------------------------------------------------------------


@pytest.mark.slow
def test_exit_after_a_timeout_never_hangs(scripted: Any) -> None:
    server = scripted(lambda index, message: None)
    code = (
        "from membrane_client import Client, Timeout\n"
        f"client = Client({server.address!r}, timeout=0.2)\n"
        "try:\n    client.ping()\nexcept Timeout:\n    print('timed out')\n"
        "second = Client('tcp://127.0.0.1:9', timeout=0.2)\n"  # left open on purpose
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=20
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "timed out"


@pytest.mark.slow
def test_client_imports_no_server_side_libraries() -> None:
    code = (
        "import sys, membrane_client, membrane_cli.client_commands, membrane_cli.dispatcher\n"
        "heavy = {'onnxruntime', 'torch', 'pydantic', 'scipy', 'cbor2', 'hdrh', 'tqdm',\n"
        "         'membrane_server', 'membrane_models'}\n"
        "print(sorted(heavy & {m.split('.')[0] for m in sys.modules}))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
