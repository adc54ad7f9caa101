"""The ZeroMQ loop: a ROUTER socket answering every request, one at a time, in one thread.

No client can stall the others: the loop never waits on a client (replies are sent without
blocking; a reply to a peer that is gone or not reading is dropped and counted), every request is
answered in bounded time, and malformed input costs one error reply. Nothing one request does
can end the loop: an exception from handling it is logged, counted and answered.

Memory per peer is bounded in bytes, not messages: the send queue's high-water mark is the
per-peer budget divided by the largest reply a hosted scene can send (docs/ROBUSTNESS.md).

Shutdown has one path: ``request_stop()`` (what SIGTERM/SIGINT call, from a signal handler or
any thread) sets a flag; the loop finishes the reply in flight, closes its socket and returns.
``stop()`` is ``request_stop()`` plus waiting for a background thread.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import resource
import signal
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from types import FrameType, TracebackType

import zmq

from membrane_client.client import DEFAULT_ADDRESS
from membrane_client.protocol import MAX_REQUEST_BYTES, ErrorCode, encode, error_reply
from membrane_errors import UserError
from membrane_server.dispatch import Answer, Dispatcher, ServedScene
from membrane_server.live import SessionTable
from membrane_server.reloading import SceneBuilder, describe_changes
from membrane_server.scene import Scene, load_scene
from membrane_server.stats import Stats

__all__ = [
    "DEFAULT_BIND",
    "DEFAULT_PEER_BUDGET",
    "SHUTDOWN_LINGER_MS",
    "BindError",
    "Server",
    "raise_open_file_limit",
    "send_queue_limit",
]

DEFAULT_BIND = DEFAULT_ADDRESS  # where clients look by default

logger = logging.getLogger(__name__)


class BindError(UserError):
    """The server cannot listen where it was told (address in use, no such interface, ...)."""


# How long the loop waits for a request before it looks at the stop flag again.
_POLL_MS = 50
# At shutdown, how long replies already handed to ZeroMQ may take to leave (a large reply to a
# slow reader needs many TCP round trips); bounded, so a stuck peer cannot hold the stop.
SHUTDOWN_LINGER_MS = 1000
_START_TIMEOUT_S = 10.0
# Bytes of replies ZeroMQ may hold for one peer that does not read (its send high-water mark is
# derived from this); a peer past it has further replies dropped, never queued.
DEFAULT_PEER_BUDGET = 1024 * 1024
# Never fewer queued replies than this per peer, whatever the budget: a client may pipeline.
_MIN_QUEUED_REPLIES = 2
# Requests (up to MAX_REQUEST_BYTES, 128 KiB, each) queued per peer before ZeroMQ stops reading
# its connection: back-pressure on that peer, nothing lost. Sized like the reply queue, from the
# peer budget (1 MiB by default: 8 requests of the largest size).
_MIN_QUEUED_REQUESTS = 8
# Spinning longer than this after a reply would only burn a core: no client polls that slowly
# and still cares about a few tens of microseconds.
_MAX_SPIN_S = 0.1
# At shutdown, how long to wait for more requests to discard once none is queued.
_DRAIN_QUIET_MS = 20
# Bytes a reply needs beyond its arrays: the envelope and the scene's other fields.
_REPLY_OVERHEAD = 4096


class Server:
    """The membrane server.

    Args:
        scenes: Scenes to host: ``ServedScene`` objects, ``Scene`` objects, built-in scene names
            or TOML paths (loaded and built here, before any socket exists).
        bind: ZeroMQ endpoint; ``tcp://127.0.0.1:*`` picks a free port (see ``address``).
        threads: onnxruntime intra-op threads per graph.
        context: ZeroMQ context (default: the process-wide shared one).
        socket_options: Extra socket options (option -> value) for the ROUTER socket, set
            before binding (e.g. CurveZMQ keys).
        peer_budget: Bytes of unread replies kept for one peer (see ``send_queue_limit``).
        spin: Seconds to keep polling without blocking after each reply (0: block at once);
            for haptic rates, a little more than the clients' period.
        sessions: The live sessions' table (default: 64 sessions, 300 s idle); it outlives
            reloads, so open sessions keep the engine they opened with.

    Raises:
        SceneError, ManifestError: A scene cannot be served (message names the cause).
    """

    def __init__(
        self,
        scenes: Iterable[ServedScene | Scene | str | Path],
        bind: str = DEFAULT_BIND,
        *,
        threads: int = 1,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
        socket_options: Mapping[int, int | bytes] | None = None,
        peer_budget: int = DEFAULT_PEER_BUDGET,
        spin: float = 0.0,
        sessions: SessionTable | None = None,
    ) -> None:
        if peer_budget < 1:
            raise ValueError(f"peer_budget must be a positive number of bytes, got {peer_budget}")
        # Scene files first (cheap), so a name clash is reported before any model is loaded.
        self._sources = list(scenes)  # kept so that a reload re-reads names and files
        self._threads = threads
        self.stats = Stats()
        self.sessions = sessions if sessions is not None else SessionTable()  # empty is falsy
        served = _load_scenes(self._sources, threads)
        self.dispatcher = Dispatcher(served, self.stats.snapshot, self.sessions)
        self.bind = bind
        self._context = context or zmq.Context.instance()
        self._socket_options = dict(socket_options or {})
        self.peer_budget = peer_budget
        if not 0.0 <= spin <= _MAX_SPIN_S:
            raise ValueError(f"spin must be between 0 and {_MAX_SPIN_S} s, got {spin}")
        self.spin = spin
        self._answered_at = -math.inf
        self._address: str | None = None
        self._stop = threading.Event()
        self._reload = threading.Event()
        self._thread: threading.Thread | None = None
        self._memory = IdleMemoryRelease()
        self._builder = SceneBuilder(lambda: _load_scenes(self._sources, self._threads))
        self._bound = threading.Event()
        self._start_error: BaseException | None = None

    @property
    def address(self) -> str:
        """The endpoint actually bound (e.g. with the port chosen for ``:*``)."""
        if self._address is None:
            raise RuntimeError("the server is not bound yet: call start() or serve_forever()")
        return self._address

    @property
    def scene_names(self) -> list[str]:
        """Names of the hosted scenes."""
        return list(self.dispatcher.scenes)

    # -- running -----------------------------------------------------------------------------

    def start(self) -> str:
        """Serve in a background thread; returns the bound address once it is bound.

        Raises:
            OSError: The endpoint cannot be bound (in use, malformed, not permitted).
        """
        if self._thread is not None:
            raise RuntimeError("the server is already running")
        self._thread = threading.Thread(target=self._run_in_thread, name="membrane-server")
        self._thread.daemon = True
        self._thread.start()
        if not self._bound.wait(_START_TIMEOUT_S):
            self.stop()
            raise BindError(f"the server did not bind {self.bind} within {_START_TIMEOUT_S} s")
        if self._start_error is not None:
            self._thread.join()
            self._thread = None
            raise self._start_error
        return self.address

    def serve_forever(self, on_bound: Callable[[str], None] | None = None) -> None:
        """Bind and serve in the calling thread until ``request_stop()`` (or a signal).

        Args:
            on_bound: Called with the bound address once bound, before serving.

        Raises:
            OSError: The endpoint cannot be bound.
        """
        socket = self._bind_socket()
        if on_bound is not None:
            try:
                on_bound(self.address)
            except BaseException:
                socket.close(linger=0)
                raise
        self._serve(socket)

    def request_stop(self) -> None:
        """Ask the loop to stop after the reply in flight. Safe from signal handlers and threads."""
        self._stop.set()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop gracefully and wait for the background thread (if ``start()`` made one)."""
        self.request_stop()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout)
            if thread.is_alive():
                logger.warning("server thread still running %.1f s after stop", timeout)

    def request_reload(self) -> None:
        """Ask for the scenes to be reloaded (what SIGHUP calls).

        Scene files and models are read again and evaluators rebuilt in a worker thread while
        the old scenes keep answering; the new ones are swapped in between two requests. If
        they fail to load, the old ones keep serving and the error is logged. A request during
        a build starts another build once it is done.
        """
        self._reload.set()

    def reload(self) -> None:
        """Reload the scenes now, in the calling thread (before serving, or in tests)."""
        self._reload.clear()
        served = self._builder.build_now()
        if served is not None:
            self._swap_in(served)

    def _swap_in(self, served: list[ServedScene]) -> None:
        changes = describe_changes(self.dispatcher.scenes, served)
        self.dispatcher = Dispatcher(served, self.stats.snapshot, self.sessions)
        logger.info("reloaded scenes: %s", changes)

    @property
    def stopping(self) -> bool:
        """True once a stop was requested."""
        return self._stop.is_set()

    def install_signal_handlers(self) -> None:
        """SIGTERM and SIGINT stop the server gracefully, SIGHUP reloads its scenes.

        Call from the main thread.
        """

        def _stop(signum: int, frame: FrameType | None) -> None:
            logger.info("signal %s: stopping", signal.Signals(signum).name)
            self.request_stop()

        def _reload(signum: int, frame: FrameType | None) -> None:
            logger.info("signal SIGHUP: reloading scenes")
            self.request_reload()

        signal.signal(signal.SIGTERM, _stop)
        signal.signal(signal.SIGINT, _stop)
        signal.signal(signal.SIGHUP, _reload)

    def __enter__(self) -> Server:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop()

    # -- internals ---------------------------------------------------------------------------

    def _run_in_thread(self) -> None:
        try:
            socket = self._bind_socket()
        except BaseException as exc:  # handed to start(), which raises it in the caller
            self._start_error = exc
            self._bound.set()
            return
        self._bound.set()
        try:
            self._serve(socket)
        except Exception:
            logger.exception("server loop failed")

    def _serve(self, socket: zmq.Socket[bytes]) -> None:
        unanswered = 0
        try:
            self._loop(socket)
            unanswered = _drain_requests(socket, SHUTDOWN_LINGER_MS / 1000)
        finally:
            socket.close(linger=SHUTDOWN_LINGER_MS)  # the reply in flight still goes out
            requests, dropped = self.stats.requests, sum(self.stats.dropped.values())
            logger.info("server on %s stopped after %d requests (%d replies dropped, "
                        "%d requests left unanswered)", self._address, requests, dropped,
                        unanswered)  # fmt: skip

    def _bind_socket(self) -> zmq.Socket[bytes]:
        socket: zmq.Socket[bytes] = self._context.socket(zmq.ROUTER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, MAX_REQUEST_BYTES)
        # A full queue or a vanished peer raises on send (counted) instead of a silent drop.
        socket.setsockopt(zmq.ROUTER_MANDATORY, 1)
        self._size_send_queue(socket)
        requests = max(_MIN_QUEUED_REQUESTS, self.peer_budget // MAX_REQUEST_BYTES)
        socket.setsockopt(zmq.RCVHWM, requests)
        for option, value in self._socket_options.items():
            socket.setsockopt(option, value)
        try:
            socket.bind(self.bind)
        except zmq.ZMQError as exc:
            socket.close(linger=0)
            raise BindError(f"cannot bind {self.bind}: {exc}") from None
        endpoint = socket.getsockopt(zmq.LAST_ENDPOINT)
        self._address = endpoint.decode() if isinstance(endpoint, bytes) else str(endpoint)
        logger.info("serving %s on %s", ", ".join(self.scene_names), self._address)
        return socket

    def _reload_between_requests(self, socket: zmq.Socket[bytes]) -> None:
        if self._reload.is_set() and self._builder.start():
            self._reload.clear()
        served = self._builder.take()
        if served is None:
            return
        self._swap_in(served)
        self._size_send_queue(socket)  # connections made from now on: sized for the new scenes

    def _size_send_queue(self, socket: zmq.Socket[bytes]) -> None:
        """Set the send high-water mark from the peer budget and the hosted scenes' replies."""
        queued = send_queue_limit(self.peer_budget, self._largest_reply_bytes())
        socket.setsockopt(zmq.SNDHWM, queued)
        logger.info("per peer: at most %d unread replies (budget %d bytes)",
                    queued, self.peer_budget)  # fmt: skip

    def _largest_reply_bytes(self) -> int:
        """The largest reply any hosted scene sends: its describe, or a float64 frame."""
        largest = 0
        for served in self.dispatcher.scenes.values():
            frame = served.evaluator.n_points * 8
            largest = max(largest, len(served.encoded_description.data), frame)
        return largest + _REPLY_OVERHEAD

    def _loop(self, socket: zmq.Socket[bytes]) -> None:
        poller = zmq.Poller()
        poller.register(socket, zmq.POLLIN)
        while not self._stop.is_set():
            self._reload_between_requests(socket)
            if not self._wait_for_requests(poller):
                self._memory.release_when_idle(self.stats.requests)
                continue
            # Drain what is queued, checking the stop flag between requests.
            while not self._stop.is_set():
                try:
                    frames = socket.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                try:
                    self._answer(socket, frames, time.perf_counter())
                except Exception:  # one request must never end the loop
                    self.stats.failures += 1
                    _log_failure()
            self._answered_at = time.perf_counter()

    def _wait_for_requests(self, poller: zmq.Poller) -> bool:
        """True once a request waits; False after ``_POLL_MS`` without one.

        With ``spin`` set, for that long after the last reply the thread polls without
        blocking: it stays on its CPU, warm, instead of sleeping and waking cold for the next
        request (a 1 kHz client's requests are answered 2-3 times faster on a virtual machine
        this way), at the cost of a core while clients are active.
        """
        if self.spin > 0.0:
            until = self._answered_at + self.spin
            while time.perf_counter() < until:
                if poller.poll(0):
                    return True
        return bool(poller.poll(_POLL_MS))

    def _answer(self, socket: zmq.Socket[bytes], frames: list[bytes], received: float) -> None:
        # ROUTER frames: [peer identity, (empty delimiter from REQ/DEALER-as-REQ), payload...].
        envelope, body = frames[:1], frames[1:]
        if body and body[0] == b"":
            envelope, body = frames[:2], frames[2:]
        try:
            answer = self.dispatcher.handle(body)
        except Exception:  # handle() never raises by contract; if it does, one reply is lost
            self.stats.failures += 1
            _log_failure()
            reply = encode(error_reply(None, ErrorCode.INTERNAL_ERROR, "the server failed"))
            answer = Answer(reply, None, str(ErrorCode.INTERNAL_ERROR))
        try:
            socket.send_multipart([*envelope, answer.reply], zmq.NOBLOCK)
        except zmq.Again:  # the peer's queue is at its budget: drop, never wait for it
            self.stats.record_dropped("peer_not_reading")
        except zmq.ZMQError as exc:
            reason = "peer_gone" if exc.errno == zmq.EHOSTUNREACH else "send_failed"
            self.stats.record_dropped(reason)
        self.stats.record(
            time.perf_counter() - received, answer.op, answer.error, answer.scene, answer.session
        )


class IdleMemoryRelease:
    """Hands freed heap memory back to the system when the server is idle.

    Replies queued for peers that never read (up to their budget each) are freed when those
    peers leave, but glibc keeps the freed small blocks in its heap: the RSS would stay at its
    peak. ``malloc_trim`` returns them; it walks the heap, so it runs only when no request
    waits, at most every ``interval`` seconds, and only after requests were served since.
    """

    def __init__(self, interval: float = 5.0) -> None:
        self._interval = interval
        self._last = time.monotonic()
        self._requests_then = 0
        self._trim = _malloc_trim()

    def release_when_idle(self, requests: int) -> None:
        """Call when the loop found nothing to do; ``requests`` is the count served so far."""
        now = time.monotonic()
        busy_since = requests != self._requests_then
        if self._trim is None or not busy_since or now - self._last < self._interval:
            return
        self._last, self._requests_then = now, requests
        self._trim(0)


def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None where the C library has none (musl, macOS)."""
    try:
        libc = ctypes.CDLL(None)
        trim: Callable[[int], int] = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    return trim


def _drain_requests(socket: zmq.Socket[bytes], limit_s: float) -> int:
    """Read and discard the requests still queued (for at most ``limit_s``); returns how many.

    Closing a TCP connection whose received data was never read makes the kernel reset it, and
    a reset throws away the replies still travelling to that client: a client that pipelined
    more requests than the server answered before stopping would lose answered replies too.
    """
    discarded, deadline = 0, time.monotonic() + limit_s
    while time.monotonic() < deadline:
        try:
            socket.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            if not socket.poll(_DRAIN_QUIET_MS, zmq.POLLIN):
                break
            continue
        discarded += 1
    return discarded


def _log_failure() -> None:
    """Log the exception being handled; even a failing log handler (a RecursionError is re-raised
    by logging's own handlers) must not end the loop."""
    with contextlib.suppress(Exception):
        logger.exception("answering one request failed; serving on")


def send_queue_limit(peer_budget: int, largest_reply: int) -> int:
    """The send high-water mark (in messages) that keeps one peer's unread replies within
    ``peer_budget`` bytes when every reply is as large as ``largest_reply``."""
    return max(_MIN_QUEUED_REPLIES, peer_budget // max(largest_reply, 1))


def raise_open_file_limit() -> tuple[int, int]:
    """Raise this process's soft limit on open files to its hard limit; returns (before, after).

    Each connected peer costs ZeroMQ a file descriptor; at the soft limit (often 1,024) new
    clients cannot connect at all. The hard limit is the operator's (systemd ``LimitNOFILE``).
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = hard if hard != resource.RLIM_INFINITY else max(soft, 1 << 20)
    if soft == resource.RLIM_INFINITY or soft >= target:
        return soft, soft
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    except (ValueError, OSError) as exc:
        logger.warning("cannot raise the open-file limit from %d to %d: %s", soft, target, exc)
        return soft, soft
    return soft, target


def _load_scenes(
    sources: Iterable[ServedScene | Scene | str | Path], threads: int
) -> list[ServedScene]:
    """Validate every scene file first (cheap, so a name clash shows before any model loads),
    then load models and build evaluators."""
    specs = [s if isinstance(s, ServedScene | Scene) else load_scene(s) for s in sources]
    names = [spec.name for spec in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"scene names must be distinct, got {names}")
    return [s if isinstance(s, ServedScene) else ServedScene.load(s, threads) for s in specs]
