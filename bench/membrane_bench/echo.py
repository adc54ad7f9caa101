"""The echo baseline for `membrane bench --baseline`: the simplest REP loop ZeroMQ allows.

It receives a request, reads its id, and replies with a msgpack map carrying a payload sized so
that the reply is as long as the real server's (to within the few bytes a growing id takes). It
runs in its own process on the same transport as the server under test, so that the load
generator, the socket types, the message sizes and the process boundary are all the same: what is
left between the two results is the server's own work.

``stall_at`` / ``stall_s`` make it sleep once (before answering request number ``stall_at``): a
server that stalls on purpose, to test how the load generator accounts for it.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.queues
import os
import queue
import tempfile
import time
import uuid
from types import TracebackType
from typing import Any
from urllib.parse import urlsplit

import msgpack
import zmq

from membrane_errors import UserError

__all__ = ["EchoError", "EchoServer", "echo_bind_address", "echo_reply_padding"]

logger = logging.getLogger(__name__)

_POLL_MS = 100  # how often an idle echo looks at its stop flag
_START_TIMEOUT_S = 30.0
_LOOPBACK = ("127.0.0.1", "localhost", "::1", "[::1]")


class EchoError(UserError):
    """The echo server cannot be placed on this transport, or did not start."""


def echo_bind_address(target: str) -> str:
    """Where to bind an echo on the same transport as ``target`` (tcp loopback or an ipc file).

    Raises:
        EchoError: ``target`` is neither ``tcp://`` nor ``ipc://`` (inproc cannot cross processes).
    """
    scheme = target.split("://", 1)[0]
    if scheme == "tcp":
        host = urlsplit(target).hostname or ""
        if host not in _LOOPBACK and host != "*":
            logger.warning(
                "baseline echo runs on loopback, the server on %s: not the same path", host
            )
        return "tcp://127.0.0.1:*"
    if scheme == "ipc":
        name = f"membrane-echo-{os.getpid()}-{uuid.uuid4().hex[:8]}.ipc"
        return f"ipc://{os.path.join(tempfile.gettempdir(), name)}"
    raise EchoError(f"cannot run a baseline beside {target!r}: use a tcp:// or ipc:// address")


def echo_reply_padding(reply_bytes: int) -> bytes:
    """The payload that makes an echo reply (with a small id) ``reply_bytes`` long, or shorter."""
    size = max(reply_bytes - len(_pack_reply(0, b"")), 0)
    while size > 0 and len(_pack_reply(0, bytes(size))) > reply_bytes:
        size -= 1  # msgpack's bin header grows from 2 to 3 to 5 bytes with the payload
    return bytes(size)


def _pack_reply(request_id: Any, payload: bytes) -> bytes:
    return msgpack.packb({"v": 1, "id": request_id, "ok": True, "payload": payload})


def _request_id(data: bytes) -> Any:
    try:
        message = msgpack.unpackb(data, raw=False)
    except (ValueError, msgpack.UnpackException):
        return None
    return message.get("id") if isinstance(message, dict) else None


def _serve(
    bind: str,
    reply_bytes: int,
    stall_at: int | None,
    stall_s: float,
    address_out: multiprocessing.queues.Queue[str],
    stop: Any,
) -> None:
    """The echo process: bind, report the address, answer until told to stop."""
    context = zmq.Context()
    socket = context.socket(zmq.REP)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, _POLL_MS)
    socket.bind(bind)
    address_out.put(socket.getsockopt_string(zmq.LAST_ENDPOINT))
    padding = echo_reply_padding(reply_bytes)
    count = 0
    try:
        while True:
            try:
                request = socket.recv()
            except zmq.Again:  # idle for a moment: the only time the stop flag is read
                if stop.is_set():
                    break
                continue
            count += 1
            if count == stall_at:
                time.sleep(stall_s)
            socket.send(_pack_reply(_request_id(request), padding))
    finally:
        socket.close(linger=0)
        context.term()


class EchoServer:
    """An echo REP server in its own process; use as a context manager.

    Args:
        target: The address of the server being compared; the echo uses the same transport.
        reply_bytes: Length of the real server's reply to the benchmarked request.
        stall_at: Sleep once before answering this request (counted from 1), for tests.
        stall_s: How long that sleep lasts, in seconds.
    """

    def __init__(
        self, target: str, reply_bytes: int, stall_at: int | None = None, stall_s: float = 0.0
    ) -> None:
        if reply_bytes < 0:
            raise EchoError(f"reply_bytes must be >= 0, got {reply_bytes}")
        self._bind = echo_bind_address(target)
        self._reply_bytes = reply_bytes
        self._stall_at = stall_at
        self._stall_s = stall_s
        self._process: multiprocessing.process.BaseProcess | None = None
        self._stop: Any = None
        self._address: str | None = None

    @property
    def address(self) -> str:
        """The bound address (after ``start``)."""
        if self._address is None:
            raise EchoError("echo server not started")
        return self._address

    def start(self) -> str:
        """Start the process and return its address once it is bound."""
        context = multiprocessing.get_context("spawn")
        address_out: multiprocessing.queues.Queue[str] = context.Queue()
        self._stop = context.Event()
        self._process = context.Process(
            target=_serve,
            args=(
                self._bind,
                self._reply_bytes,
                self._stall_at,
                self._stall_s,
                address_out,
                self._stop,
            ),
            name="membrane-echo",
            daemon=True,
        )
        self._process.start()
        give_up = time.monotonic() + _START_TIMEOUT_S
        while self._address is None:
            try:
                self._address = address_out.get(timeout=0.1)
            except queue.Empty:
                if not self._process.is_alive() or time.monotonic() > give_up:
                    self.stop()
                    raise EchoError(f"echo server did not bind {self._bind}") from None
        logger.info("echo baseline on %s (%d-byte replies)", self._address, self._reply_bytes)
        return self._address

    def stop(self) -> None:
        """Stop the process (it notices within 0.1 s when idle; killed after 5 s)."""
        if self._process is None:
            return
        self._stop.set()
        self._process.join(timeout=5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(timeout=5.0)
        self._process = None
        if self._address is not None and self._address.startswith("ipc://"):
            with contextlib.suppress(OSError):
                os.unlink(self._address.removeprefix("ipc://"))

    def __enter__(self) -> EchoServer:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop()
