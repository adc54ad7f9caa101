"""The ZeroMQ loop: a ROUTER socket answering every request, one at a time, in one thread.

No client can stall the others: the loop never waits on a client (replies are sent without
blocking; a reply to a peer that is gone or not reading is dropped and counted), every request is
answered in bounded time, and malformed input costs one error reply. Nothing one request does
can end the loop: an exception from handling it is logged, counted and answered.

Memory per peer is bounded (docs/ROBUSTNESS.md): the send queue's high-water mark is what
the per-peer budget holds of the largest reply a hosted scene can send, and never less than
twice ``max_in_flight`` (so that a client that reads its replies and keeps at most that many
requests in flight loses none; ``max_in_flight`` itself is what the budget allows, and never
less than a live session at its scene's rate needs). Freed memory is handed back to the system
on a schedule, between requests, busy or idle (``MemoryRelease``).

Shutdown has one path: ``request_stop()`` (what SIGTERM/SIGINT call, from a signal handler or
any thread) sets a flag; the loop finishes the reply in flight, closes its socket and returns.
``stop()`` is ``request_stop()`` plus waiting for a background thread.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import logging
import math
import os
import resource
import signal
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

import zmq

from membrane_client.client import DEFAULT_ADDRESS
from membrane_client.protocol import (
    MAX_BATCH_STEPS,
    MAX_REQUEST_BYTES,
    ErrorCode,
    encode,
    error_reply,
)
from membrane_errors import UserError
from membrane_models.live import PreparingEngine, WaitingEngine
from membrane_server.dispatch import Answer, Dispatcher
from membrane_server.heap import keep_temporaries_in_heap, malloc_trim_function
from membrane_server.reloading import SceneBuilder, describe_changes
from membrane_server.scene import Scene, SceneError, load_scene
from membrane_server.served import ServedScene
from membrane_server.sessions import SessionTable
from membrane_server.stats import Stats

__all__ = [
    "DEFAULT_BIND",
    "DEFAULT_IN_FLIGHT",
    "DEFAULT_PEER_BUDGET",
    "MAX_BATCH",
    "MAX_RETIRED_SCENES",
    "SHUTDOWN_LINGER_MS",
    "BindError",
    "MemoryRelease",
    "Server",
    "max_in_flight",
    "raise_open_file_limit",
    "send_high_water_mark",
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
# Requests a peer may keep in flight with no reply lost: up to this many as the budget holds
# twice over in the largest replies (at least one), and never fewer than _IN_FLIGHT_S of the
# fastest live scene's steps (a session at the scene's rate 1/dt pipelining over a round trip
# that long; a session that waits for each reply needs one), at most _MAX_IN_FLIGHT.
DEFAULT_IN_FLIGHT = 16
_IN_FLIGHT_S = 0.01
_MAX_IN_FLIGHT = 1024
# Scene objects a reload swapped out that open sessions may still hold; past it, the oldest
# one's sessions are closed (each old 100 x 100 live scene holds tens of MiB).
MAX_RETIRED_SCENES = 4
# How often the loop looks after its upkeep (a reload to swap in, peers gone, memory to hand
# back) while requests keep coming.
_UPKEEP_S = 0.01
# The most requests taken from the queue to answer together (their steps batched: a `steps`
# request's bound), and about the most bytes (64 of the largest requests).
MAX_BATCH = MAX_BATCH_STEPS
_MAX_QUEUED_BYTES = 64 * MAX_REQUEST_BYTES


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
        peer_budget: Bytes of unread replies kept for one peer (see ``send_high_water_mark``).
        spin: Seconds to keep polling without blocking after each reply (0: block at once);
            for haptic rates, a little more than the clients' period.
        sessions: The live sessions' table (default: 64 sessions, 300 s idle); it outlives
            reloads, so open sessions keep the engine they opened with.
        max_batch: The most requests taken from the queue at once and answered together (their
            steps of loads alone stepped as one operation, ``Dispatcher.handle_many``); 1
            answers each alone: the first of a burst is not held while the rest are stepped.

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
        workers: Sequence[str] = (),
        max_batch: int = MAX_BATCH,
    ) -> None:
        if not 1 <= max_batch <= MAX_BATCH:
            raise ValueError(f"max_batch must be between 1 and {MAX_BATCH}, got {max_batch}")
        self.max_batch = max_batch
        if peer_budget < 1:
            raise ValueError(f"peer_budget must be a positive number of bytes, got {peer_budget}")
        # Scene files first (cheap), so a name clash is reported before any model is loaded.
        self._sources = list(scenes)  # kept so that a reload re-reads names and files
        self._threads = threads
        self.stats = Stats()
        self.sessions = sessions if sessions is not None else SessionTable()  # empty is falsy
        self.workers = tuple(workers)  # every worker's endpoint, when one of several
        served = _load_scenes(self._sources, threads)
        self.dispatcher = self._dispatcher(served)
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
        self._memory = MemoryRelease()
        keep_temporaries_in_heap()  # the trims above hand back what the heap then keeps
        self._curve = bool(self._socket_options.get(zmq.CURVE_SERVER))
        self._monitor: zmq.Socket[bytes] | None = None
        self._send_queue: int | None = None  # the send high-water mark in force, once bound
        self._upkeep_at = -math.inf
        self._retired: list[_Retired] = []  # swapped-out scenes, oldest first
        self._retired_seen = 0
        self._reloads = collections.Counter[str]()
        self._builder = SceneBuilder(lambda: _load_scenes(self._sources, self._threads))
        self._bound = threading.Event()
        self._start_error: BaseException | None = None
        self.stats.add_figures("peers", self._peer_figures)
        self.stats.add_figures("memory", self._memory.snapshot)
        self.stats.add_figures("reloads", self._reload_figures)

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

    def _dispatcher(self, served: list[ServedScene]) -> Dispatcher:
        for scene in served:  # work an engine starts before its first session (a worker)
            if isinstance(scene.live, PreparingEngine):
                scene.live.prepare()
        # hello's per-peer figures through a weak reference: no dispatcher keeps the server
        server = weakref.proxy(self)
        return Dispatcher(
            served, self.stats.snapshot, self.sessions, lambda: server.limits, self.workers
        )

    @property
    def max_in_flight(self) -> int:
        """Requests one peer may keep in flight without losing a reply (``max_in_flight``):
        what the hosted scenes call for, within half the send queue in force."""
        wanted = max_in_flight(
            self.dispatcher.scenes.values(), self.peer_budget, self._largest_reply_bytes()
        )
        return wanted if self._send_queue is None else min(wanted, self._send_queue // 2)

    @property
    def limits(self) -> dict[str, int]:
        """What ``hello`` states of the per-peer limits: requests in flight with no reply lost,
        and the bytes of unread replies kept for a peer."""
        return {"max_in_flight": self.max_in_flight, "peer_budget_bytes": self.peer_budget}

    def _swap_in(self, served: list[ServedScene]) -> None:
        """Serve the new scenes. A scene whose revision did not change keeps the object already
        serving (and its reply cache); one whose revision an old, still held object has gets
        that object back: no two objects of one revision are ever alive. The objects swapped
        out are watched (weak references) until the sessions that hold them close."""
        current = self.dispatcher.scenes
        changes = describe_changes(current, served)
        kept = [self._reuse(new, current) for new in served]
        swapped_out = [old for old in current.values() if all(old is not k for k in kept)]
        self.dispatcher = self._dispatcher(kept)
        self._retired += [_Retired(old.name, old.revision, weakref.ref(old)) for old in swapped_out]
        self._retired_seen = len(self._retired)
        del current, swapped_out, served  # the old scenes go with the last session holding them
        self._reloads["count"] += 1
        logger.info("reloaded scenes: %s", changes)
        self._bound_retired_scenes()
        self._memory.arm()

    def _reuse(self, new: ServedScene, current: Mapping[str, ServedScene]) -> ServedScene:
        serving = current.get(new.name)
        if serving is not None and serving.revision == new.revision:
            return serving
        for index, retired in enumerate(self._retired):
            held = retired.scene()
            if held is not None and held.revision == new.revision:
                del self._retired[index]
                return held
        return new

    def _retired_held(self) -> list[_Retired]:
        """The swapped-out scenes still alive (forgetting the others)."""
        self._retired = [retired for retired in self._retired if retired.scene() is not None]
        return self._retired

    def _bound_retired_scenes(self) -> None:
        """Past MAX_RETIRED_SCENES old scenes held, close the sessions on the oldest ones."""
        held = self._retired_held()
        excess = len(held) - MAX_RETIRED_SCENES
        for retired in [r for r in held if not r.closed][: max(0, excess)]:
            retired.closed = True
            closed = self.sessions.close_revision(retired.revision)
            self._reloads["sessions_closed"] += closed
            logger.warning(
                "reload: %d old scene revisions held by open sessions, more than %d: closed the "
                "%d sessions on %s revision %s, the oldest",
                len(held), MAX_RETIRED_SCENES, closed, retired.name, retired.revision,
            )  # fmt: skip
        self._retired_held()

    def _reload_figures(self) -> dict[str, int]:
        return {
            "count": self._reloads["count"],
            "revisions_held": len(self._retired_held()),
            "max_revisions_held": MAX_RETIRED_SCENES,
            "sessions_closed": self._reloads["sessions_closed"],
        }

    def _peer_figures(self) -> dict[str, int]:
        return {
            **self.limits,
            "send_queue": self._send_queue or self._send_high_water_mark(),
            "largest_reply_bytes": self._largest_reply_bytes(),
        }

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
        # What start-up made (modules, scenes, compiled loops: about 96,000 objects) is kept out
        # of the cyclic collector's full passes, which the serving thread runs when a reload's
        # building allocates: a pass over them took 60-70 ms, a step's worth of stall. Freed
        # objects still go by reference counting (the scenes are kept free of cycles for that).
        gc.collect()
        gc.freeze()
        try:
            self._loop(socket)
            unanswered = _drain_requests(socket, SHUTDOWN_LINGER_MS / 1000)
        finally:
            self._close_monitor(socket)
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
        self._monitor = _disconnect_monitor(socket)
        logger.info("serving %s on %s", ", ".join(self.scene_names), self._address)
        return socket

    def _close_monitor(self, socket: zmq.Socket[bytes]) -> None:
        monitor, self._monitor = self._monitor, None
        if monitor is not None:
            with contextlib.suppress(zmq.ZMQError):
                socket.disable_monitor()
            monitor.close(linger=0)

    def _reload_between_requests(self, socket: zmq.Socket[bytes]) -> None:
        if self._reload.is_set() and self._builder.start():
            self._reload.clear()
        served = self._builder.take()
        if served is None:
            return
        self._swap_in(served)
        wanted = self._send_high_water_mark()
        if wanted != self._send_queue:  # said once per reload that changes it
            logger.warning(
                "reload: the reloaded scenes call for a send queue of %d replies per peer; it "
                "stays %d until a restart (ZeroMQ sets it when the socket binds)",
                wanted, self._send_queue,
            )  # fmt: skip

    def _size_send_queue(self, socket: zmq.Socket[bytes]) -> None:
        """Set the send high-water mark for the hosted scenes. Before binding: ZeroMQ's listener
        copies the socket's options then, and gives every connection it accepts those."""
        self._send_queue = self._send_high_water_mark()
        socket.setsockopt(zmq.SNDHWM, self._send_queue)
        logger.info("per peer: %d requests in flight with no reply lost, a send queue of %d "
                    "replies (budget %d bytes)", self.max_in_flight, self._send_queue,
                    self.peer_budget)  # fmt: skip

    def _send_high_water_mark(self) -> int:
        in_flight = max_in_flight(
            self.dispatcher.scenes.values(), self.peer_budget, self._largest_reply_bytes()
        )
        return send_high_water_mark(self.peer_budget, self._largest_reply_bytes(), in_flight)

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
        if self._monitor is not None:
            poller.register(self._monitor, zmq.POLLIN)
        while not self._stop.is_set():
            busy = self._wait_for_requests(poller)
            # Drain what is queued, checking the stop flag between requests.
            while busy and not self._stop.is_set():
                queued = self._receive_queued(socket)
                if not queued:
                    break
                try:
                    self._answer_queued(socket, queued)
                except Exception:  # one request must never end the loop
                    self.stats.failures += 1
                    _log_failure()
                now = time.perf_counter()
                if now >= self._upkeep_at:
                    self._upkeep(socket, now, idle=False, queued=True)
            # Nothing queued now: a periodic client's next request is furthest away.
            self._upkeep(socket, time.perf_counter(), idle=not busy)
            if busy:
                self._answered_at = time.perf_counter()

    def _receive(self, socket: zmq.Socket[bytes]) -> tuple[list[bytes], str]:
        """The next request's frames and who sent it: its CurveZMQ key with Curve (the ZAP
        handler's User-Id, read from a frame's metadata), else its connection."""
        if not self._curve:
            frames = socket.recv_multipart(zmq.NOBLOCK)
            return frames, "conn:" + frames[0].hex()
        parts = socket.recv_multipart(zmq.NOBLOCK, copy=False)
        frames = [part.bytes for part in parts]
        try:
            return frames, f"key:{parts[-1].get('User-Id')}"
        except zmq.ZMQError:  # no metadata (a socket made without the authenticator)
            return frames, "conn:" + frames[0].hex()

    def _receive_queued(self, socket: zmq.Socket[bytes]) -> list[tuple[list[bytes], str, float]]:
        """The requests waiting now (none is waited for), each with its peer and when it was
        taken: at most ``max_batch`` of them and about ``_MAX_QUEUED_BYTES``, so that a burst
        is answered in bounded pieces and memory."""
        queued: list[tuple[list[bytes], str, float]] = []
        size = 0
        while len(queued) < self.max_batch and size < _MAX_QUEUED_BYTES:
            try:
                frames, peer = self._receive(socket)
            except zmq.Again:
                break
            queued.append((frames, peer, time.perf_counter()))
            size += sum(len(frame) for frame in frames)
        return queued

    def _answer_queued(
        self, socket: zmq.Socket[bytes], queued: list[tuple[list[bytes], str, float]]
    ) -> None:
        """Answer what was queued together (``Dispatcher.handle_many``: its runs of steps of
        loads alone are stepped as one operation per engine), each reply sent as it would be
        alone."""
        if len(queued) == 1:
            frames, peer, received = queued[0]
            self._answer(socket, frames, received, peer)
            return
        envelopes, requests = [], []
        for frames, peer, _ in queued:
            envelope, body = _split_envelope(frames)
            envelopes.append(envelope)
            requests.append((body, peer))
        answers = self.dispatcher.handle_many(requests)
        for index, (envelope, (_, _, received)) in enumerate(zip(envelopes, queued, strict=True)):
            try:
                answer = next(answers)
            except Exception:  # handle_many() never raises by contract; if it does, the one
                self.stats.failures += 1  # request is lost to the failure, and the rest are
                _log_failure()  # answered afresh
                failed = encode(error_reply(None, ErrorCode.INTERNAL_ERROR, "the server failed"))
                answer = Answer(failed, None, str(ErrorCode.INTERNAL_ERROR))
                answers = self.dispatcher.handle_many(requests[index + 1 :])
            self._send(socket, envelope, answer.reply)
            took = time.perf_counter() - received
            self.stats.record(took, answer.op, answer.error, answer.scene, answer.session)

    def _upkeep(
        self, socket: zmq.Socket[bytes], now: float, idle: bool, queued: bool = False
    ) -> None:
        """Between two requests: swap in a reload, note peers gone and old scenes freed, hand
        freed memory back when due (``queued``: requests may be waiting, so the trim waits for
        a moment without, up to a second). Never raises: upkeep must not end the loop."""
        self._upkeep_at = now + _UPKEEP_S
        try:
            self._reload_between_requests(socket)
            if self._monitor is not None and _drain_events(self._monitor):
                self._memory.arm()  # a peer that left freed its queued replies
            if self._retired:
                held = len(self._retired_held())
                if held < self._retired_seen:  # the last session on an old scene closed
                    self._memory.arm()
                self._retired_seen = held
            self._memory.tick(now, idle, self.stats.requests, queued)
        except Exception:
            self.stats.failures += 1
            with contextlib.suppress(Exception):
                logger.exception("upkeep between requests failed; serving on")

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

    def _answer(
        self, socket: zmq.Socket[bytes], frames: list[bytes], received: float, peer: str = ""
    ) -> None:
        envelope, body = _split_envelope(frames)
        try:
            answer = self.dispatcher.handle(body, peer)
        except Exception:  # handle() never raises by contract; if it does, one reply is lost
            self.stats.failures += 1
            _log_failure()
            reply = encode(error_reply(None, ErrorCode.INTERNAL_ERROR, "the server failed"))
            answer = Answer(reply, None, str(ErrorCode.INTERNAL_ERROR))
        self._send(socket, envelope, answer.reply)
        self.stats.record(
            time.perf_counter() - received, answer.op, answer.error, answer.scene, answer.session
        )

    def _send(self, socket: zmq.Socket[bytes], envelope: list[bytes], reply: bytes) -> None:
        """Hand a reply to ZeroMQ without waiting: dropped and counted when the peer's queue is
        full or the peer is gone."""
        try:
            socket.send_multipart([*envelope, reply], zmq.NOBLOCK)
        except zmq.Again:
            # The queue looks full. A socket learns what its peer side took from commands it
            # reads at most every millisecond or so while it sends; reading them now (what
            # ZMQ_EVENTS does) tells a queue that is full from one that was emptied since.
            socket.getsockopt(zmq.EVENTS)
            try:
                socket.send_multipart([*envelope, reply], zmq.NOBLOCK)
            except zmq.Again:  # still full: drop, never wait for it
                self.stats.record_dropped("peer_not_reading")
            except zmq.ZMQError as exc:
                self._record_send_error(exc)
        except zmq.ZMQError as exc:
            self._record_send_error(exc)

    def _record_send_error(self, exc: zmq.ZMQError) -> None:
        self.stats.record_dropped("peer_gone" if exc.errno == zmq.EHOSTUNREACH else "send_failed")


class _Retired:
    """A scene a reload swapped out, watched until nothing holds it."""

    __slots__ = ("closed", "name", "revision", "scene")

    def __init__(self, name: str, revision: str, scene: weakref.ref[ServedScene]) -> None:
        self.name, self.revision, self.scene = name, revision, scene
        self.closed = False  # its sessions were closed (past the bound)


class MemoryRelease:
    """Hands freed heap memory back to the system on a schedule, busy or idle.

    Replies queued for peers that never read are freed when those peers leave, but glibc keeps
    freed small blocks in its heap: the RSS would stay at its peak. ``malloc_trim`` returns
    them; it walks the heap (1 to 40 ms on heaps of 250 to 700 MiB, under a millisecond on a
    compact one), so it runs between requests, preferably when none waits, and only when
    memory was likely freed: a peer's connection ended (its queued replies go with it), a
    reload swapped scenes out, an old scene was freed (``arm``); at most every ``interval``
    seconds. Trimming while memory grows would free nothing and cost the walk, so growth alone
    (``growth`` bytes above the RSS after the last trim) trims only every ``growth_interval``
    seconds; an idle loop trims every ``idle_interval`` seconds after serving requests.
    """

    def __init__(
        self,
        interval: float = 0.5,
        growth: int = 32 * 1024 * 1024,
        growth_interval: float = 10.0,
        idle_interval: float = 5.0,
        check_interval: float = 0.1,
        max_defer: float = 1.0,
        trim: Callable[[int], int] | None = None,
        rss: Callable[[], int | None] | None = None,
    ) -> None:
        self.interval, self.growth, self.growth_interval = interval, growth, growth_interval
        self.idle_interval, self._check_interval = idle_interval, check_interval
        self.max_defer = max_defer
        self._trim = trim if trim is not None else malloc_trim_function()
        self._rss = rss if rss is not None else _resident_bytes
        self._armed = False
        self._due_at: float | None = None  # when a trim became due that is still waiting
        self._last = -math.inf
        self._next_check = -math.inf
        self._requests_then = 0
        self._floor = self._rss() or 0  # the RSS after the last trim
        self.trims = 0
        self.released = 0
        self.last_trim_s = 0.0
        self.max_trim_s = 0.0

    def arm(self) -> None:
        """Memory was likely freed: trim once the interval allows."""
        self._armed = True

    def tick(self, now: float, idle: bool, requests: int, queued: bool = False) -> bool:
        """Call between requests (``now`` from ``time.perf_counter``); True when it trimmed.

        ``queued``: requests may be waiting. A due trim then waits, for at most ``max_defer``
        seconds, for a call without: right after the queue emptied, the next request of a
        periodic client is furthest away, and a trim delays nobody.
        """
        if self._trim is None:
            return False
        if self._due_at is None:
            if now < self._next_check:
                return False
            self._next_check = now + self._check_interval
            if not self._due(now, idle, requests):
                return False
            self._due_at = now
        if queued and now - self._due_at < self.max_defer:
            return False
        self._due_at = None
        rss = self._rss()
        started = time.perf_counter()
        self._trim(0)
        took = time.perf_counter() - started
        after = self._rss()
        self._last, self._armed, self._requests_then = now, False, requests
        self.trims += 1
        self.last_trim_s, self.max_trim_s = took, max(self.max_trim_s, took)
        if rss is not None and after is not None:
            self.released += max(0, rss - after)
            self._floor = after
        return True

    def _due(self, now: float, idle: bool, requests: int) -> bool:
        since = now - self._last
        if self._armed and since >= self.interval:
            return True
        if idle and requests != self._requests_then and since >= self.idle_interval:
            return True
        if since >= self.growth_interval:
            rss = self._rss()
            return rss is not None and rss > self._floor + self.growth
        return False

    def snapshot(self) -> dict[str, Any]:
        """The ``stats`` reply's ``memory`` figures."""
        return {
            "rss_bytes": self._rss(),
            "trims": self.trims,
            "released_bytes": self.released,
            "last_trim_ms": self.last_trim_s * 1e3,
            "max_trim_ms": self.max_trim_s * 1e3,
        }


_STATM = "/proc/self/statm"
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def _resident_bytes() -> int | None:
    """This process's resident memory (Linux: /proc/self/statm, a few microseconds), or None."""
    try:
        with open(_STATM, "rb") as statm:
            return int(statm.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def _disconnect_monitor(socket: zmq.Socket[bytes]) -> zmq.Socket[bytes] | None:
    """A socket that gets an event each time a peer's connection ends (its queued replies are
    freed then), or None where monitoring is not available."""
    try:
        return socket.get_monitor_socket(zmq.EVENT_DISCONNECTED)
    except (zmq.ZMQError, NotImplementedError) as exc:
        logger.debug("no connection monitor: %s", exc)
        return None


def _split_envelope(frames: list[bytes]) -> tuple[list[bytes], list[bytes]]:
    """ROUTER frames: [peer identity, (empty delimiter from REQ/DEALER-as-REQ), payload...]."""
    envelope, body = frames[:1], frames[1:]
    if body and body[0] == b"":
        envelope, body = frames[:2], frames[2:]
    return envelope, body


def _drain_events(monitor: zmq.Socket[bytes], limit: int = 1000) -> int:
    """Read the monitor's queued events (at most ``limit``); returns how many."""
    for count in range(limit):
        try:
            monitor.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return count
    return limit


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
    """How many replies as large as ``largest_reply`` fit ``peer_budget`` bytes (at least 2)."""
    return max(_MIN_QUEUED_REPLIES, peer_budget // max(largest_reply, 1))


def send_high_water_mark(peer_budget: int, largest_reply: int, in_flight: int) -> int:
    """The send queue's length in messages: as many replies as large as ``largest_reply`` as
    fit ``peer_budget`` bytes, and never fewer than twice ``in_flight``. Twice, because ZeroMQ
    learns that its peer side took messages in batches of half the mark: with a mark of 2n, n
    replies in flight always fit."""
    return max(2 * in_flight, send_queue_limit(peer_budget, largest_reply))


def max_in_flight(scenes: Iterable[ServedScene], peer_budget: int, largest_reply: int) -> int:
    """Requests one peer may keep in flight with no reply lost: as many as the budget holds
    twice over in the largest replies, up to DEFAULT_IN_FLIGHT (at least one), and never fewer than
    the fastest live scene's steps over 10 ms (at most 1,024)."""
    rates = [1.0 / served.scene.dt for served in scenes if served.live is not None]
    needed = math.ceil(_IN_FLIGHT_S * max(rates) - 1e-9) if rates else 1
    affordable = min(DEFAULT_IN_FLIGHT, peer_budget // max(2 * largest_reply, 1))
    return min(_MAX_IN_FLIGHT, max(1, needed, affordable))


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
    served = [s if isinstance(s, ServedScene) else ServedScene.load(s, threads) for s in specs]
    for scene in served:  # a step that waits seconds would hold every client's requests
        if isinstance(scene.live, WaitingEngine) and scene.live.step_waits is not None:
            raise scene.scene.error(
                SceneError(
                    f"{scene.live.step_waits}, which would hold every client's requests: a "
                    "server does not serve it (step the engine in-process)"
                )
            )
    return served
