"""The load generator behind `membrane bench`: open and closed loops from N client processes.

Each client process owns one DEALER socket and speaks the REQ envelope (an empty delimiter frame,
then the message), so it talks to a REP or a ROUTER server exactly as a REQ client would, but never
gets stuck in REQ's send/receive state machine after a timeout.

Open loop (``rate``): client i of n sends request k at its due time
``start + (k + i / n) / client_rate``, one request in flight, like a simulator polling once per
step. When a reply comes late the next request goes out at once, and its latency still counts from
its *due* time, not from when it was sent: the correction for coordinated omission that wrk2
makes. A reply later than the deadline (by default one client period) is a missed deadline;
requests still waiting to go out when the window ends are counted ``unsent`` (the server fell
behind the rate). The uncorrected send-to-receive time is kept too, as ``service``, to show what
the correction adds.

Closed loop (``concurrency``): each client keeps its share of the requests in flight; a reply
triggers the next request, and latency is send-to-receive.

Live steps (``step``, ``step-frames``): each client process opens a live session of its own
before the run and closes it after; its requests step it with one probe pressing at
``probe_at`` (the server's haptic path), without frames or with them.

Every loop is bounded: a request without a reply after ``timeout`` counts as a ``timeout`` error,
and each process stops ``timeout`` after the end of the run at the latest.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import multiprocessing.queues
import queue
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import zmq
from hdrh.histogram import HdrHistogram

from membrane_client.live_schema import Probe, Tool
from membrane_client.protocol import Op, Request, peek_reply
from membrane_errors import UserError

__all__ = [
    "PAYLOADS",
    "PERCENTILES",
    "LoadError",
    "LoadResult",
    "LoadSpec",
    "Mode",
    "Payload",
    "run_load",
]

logger = logging.getLogger(__name__)

Mode = Literal["open", "closed"]
Payload = Literal["query", "ping", "step", "step-frames"]
PAYLOADS: tuple[Payload, ...] = ("query", "ping", "step", "step-frames")
# The probe of a live step: a light press (problem units) with a membrane-sized footprint.
STEP_DEPTH, STEP_RADIUS = 1e-4, 0.05
_OPEN_ID = 2**62  # the session's open and close: ids no step of a run reaches

# Reported percentiles: label -> percentile.
PERCENTILES: dict[str, float] = {"p50": 50.0, "p90": 90.0, "p99": 99.0, "p99.9": 99.9}

# Histogram range in microseconds: 1 us to one hour, 3 significant digits (HdrHistogram's usual).
_LOWEST_US = 1
_HIGHEST_US = 3_600_000_000
_DIGITS = 3

# time.sleep overshoots by 50-100 us on Linux: sleep until this margin before a due time, then
# spin. Spinning only this long keeps the client from stealing a core from the server.
_SPIN_MARGIN_NS = 150_000
_STARTUP_TIMEOUT_S = 60.0
_START_DELAY_NS = 100_000_000  # lets every client reach its first due time on schedule


class _SharedInt(Protocol):
    """A shared-memory integer (``multiprocessing`` RawValue "q")."""

    value: int


class LoadError(UserError):
    """A load that cannot be run as specified, or clients that failed to start or finish."""


@dataclass(frozen=True)
class LoadSpec:
    """What load to generate.

    Attributes:
        mode: ``"open"`` (fixed rate) or ``"closed"`` (fixed number in flight).
        rate: Total requests per second over all clients (open loop).
        concurrency: Total requests in flight over all clients (closed loop).
        clients: Number of client processes.
        duration: Measured seconds.
        warmup: Seconds of load before measuring (not recorded).
        payload: ``"query"`` (cycling through ``times``), ``"ping"``, or a live ``"step"``
            (forces only) or ``"step-frames"`` (with the frame).
        times: The query times, in the order they are cycled through.
        scene: Scene name to put in every request (servers hosting several scenes), or None.
        timeout: Seconds without a reply after which a request counts as a timeout.
        deadline: Open loop: latency above this many seconds is a missed deadline; None means one
            client period (the time until that client's next request is due).
        session: Session id prefix; client i sends ``f"{session}-{i}"`` with every request, as a
            real client sends its own session id. None sends none (a live step needs one: it
            then uses ``"bench"``).
        probe_at: Where a live step's probe presses (lattice coordinates of the scene).
        probe_radius: Its footprint's radius (one the scene's engine carries).
        press: What presses there: a "probe", or a "tool" (a sphere of ``probe_radius``) for
            an engine that takes rigid tools only.
    """

    mode: Mode
    rate: float = 0.0
    concurrency: int = 0
    clients: int = 1
    duration: float = 10.0
    warmup: float = 1.0
    payload: Payload = "query"
    times: tuple[float, ...] = (0.0,)
    scene: str | None = None
    timeout: float = 1.0
    deadline: float | None = None
    session: str | None = None
    probe_at: tuple[float, ...] = (0.5, 0.5)
    probe_radius: float = STEP_RADIUS
    press: str = "probe"

    def __post_init__(self) -> None:
        _require(self.mode in ("open", "closed"), f"mode must be open or closed, not {self.mode}")
        _require(self.payload in PAYLOADS, f"unknown payload {self.payload!r}")
        _require(self.clients >= 1, f"clients must be >= 1, got {self.clients}")
        _require(_positive(self.duration), f"duration must be > 0 s, got {self.duration}")
        _require(self.warmup >= 0 and math.isfinite(self.warmup), "warmup must be >= 0 s")
        _require(_positive(self.timeout), f"timeout must be > 0 s, got {self.timeout}")
        _require(len(self.times) > 0, "times must not be empty")
        _require(all(math.isfinite(t) for t in self.times), "times must be finite")
        if self.mode == "open":
            _require(_positive(self.rate), f"rate must be > 0 Hz, got {self.rate}")
            _require(self.deadline is None or _positive(self.deadline), "deadline must be > 0 s")
        else:
            _require(
                self.concurrency >= self.clients,
                f"concurrency ({self.concurrency}) must be at least the number of clients "
                f"({self.clients})",
            )

    @property
    def client_rate(self) -> float:
        """Requests per second from one client (open loop)."""
        return self.rate / self.clients

    @property
    def deadline_s(self) -> float | None:
        """The missed-deadline threshold in seconds (open loop), else None."""
        if self.mode != "open":
            return None
        return self.deadline if self.deadline is not None else 1.0 / self.client_rate

    def in_flight(self, client: int) -> int:
        """Requests client number ``client`` keeps in flight (closed loop); shares differ by 1."""
        base, extra = divmod(self.concurrency, self.clients)
        return base + (1 if client < extra else 0)


def _positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise LoadError(message)


def new_histogram() -> HdrHistogram:
    """An empty latency histogram in microseconds."""
    return HdrHistogram(_LOWEST_US, _HIGHEST_US, _DIGITS)


@dataclass
class _Tally:
    """What one client saw in the measured window (merged across clients by ``LoadResult``)."""

    latency: HdrHistogram = field(default_factory=new_histogram)
    service: HdrHistogram = field(default_factory=new_histogram)
    sent: int = 0
    replies: int = 0
    ok: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    missed_deadlines: int = 0
    late_replies: int = 0
    unsent: int = 0

    def record(self, due_ns: int, sent_ns: int, received_ns: int, code: str | None) -> None:
        self.replies += 1
        if code is None:
            self.ok += 1
        else:
            self.errors[code] += 1
        self.latency.record_value(_to_us(received_ns - due_ns))
        self.service.record_value(_to_us(received_ns - sent_ns))

    def to_wire(self) -> dict[str, Any]:
        """Plain, picklable data (histograms in their compressed encoding)."""
        return {
            "latency": self.latency.encode(),
            "service": self.service.encode(),
            "sent": self.sent,
            "replies": self.replies,
            "ok": self.ok,
            "errors": dict(self.errors),
            "missed_deadlines": self.missed_deadlines,
            "late_replies": self.late_replies,
            "unsent": self.unsent,
        }


def _to_us(nanoseconds: int) -> int:
    return min(max(nanoseconds // 1000, _LOWEST_US), _HIGHEST_US)


@dataclass
class LoadResult:
    """The merged outcome of one load run against one address.

    ``unsent`` counts open-loop requests that fell due in the measured window but were still
    waiting to go out when it ended (the server could not keep up with the rate).

    Latencies are in microseconds; ``latency`` counts from each request's due time in the open
    loop (corrected for coordinated omission) and from its send time in the closed loop;
    ``service`` is always send-to-receive.
    """

    label: str
    address: str
    spec: LoadSpec
    latency: HdrHistogram
    service: HdrHistogram
    sent: int
    replies: int
    ok: int
    errors: dict[str, int]
    missed_deadlines: int | None
    late_replies: int
    unsent: int = 0

    @property
    def throughput(self) -> float:
        """Replies per second to the requests of the measured window."""
        return self.replies / self.spec.duration

    def percentiles(self, which: str = "latency") -> dict[str, float]:
        """p50 ... p99.9, max and mean of ``latency`` or ``service``, in microseconds."""
        histogram = self.latency if which == "latency" else self.service
        if histogram.get_total_count() == 0:
            return {**{label: math.nan for label in PERCENTILES}, "max": math.nan, "mean": math.nan}
        values = {
            label: float(histogram.get_value_at_percentile(p)) for label, p in PERCENTILES.items()
        }
        values["max"] = float(histogram.get_max_value())
        values["mean"] = float(histogram.get_mean_value())
        return values

    def summary(self) -> dict[str, Any]:
        """Everything as plain data (for JSON)."""
        return {
            "label": self.label,
            "address": self.address,
            "sent": self.sent,
            "replies": self.replies,
            "ok": self.ok,
            "errors": dict(sorted(self.errors.items())),
            "error_count": sum(self.errors.values()),
            "missed_deadlines": self.missed_deadlines,
            "late_replies": self.late_replies,
            "unsent": self.unsent,
            "throughput_hz": self.throughput,
            "latency_us": self.percentiles("latency"),
            "service_us": self.percentiles("service"),
        }

    @classmethod
    def merge(
        cls, label: str, address: str, spec: LoadSpec, parts: Sequence[dict[str, Any]]
    ) -> LoadResult:
        """Combine the clients' tallies (``_Tally.to_wire`` dicts)."""
        latency, service = new_histogram(), new_histogram()
        errors: Counter[str] = Counter()
        for part in parts:
            latency.add(HdrHistogram.decode(part["latency"]))
            service.add(HdrHistogram.decode(part["service"]))
            errors.update(part["errors"])
        return cls(
            label=label,
            address=address,
            spec=spec,
            latency=latency,
            service=service,
            sent=sum(p["sent"] for p in parts),
            replies=sum(p["replies"] for p in parts),
            ok=sum(p["ok"] for p in parts),
            errors=dict(errors),
            # A request still unsent when the run ended missed its deadline too.
            missed_deadlines=(
                sum(p["missed_deadlines"] + p["unsent"] for p in parts)
                if spec.mode == "open"
                else None
            ),
            late_replies=sum(p["late_replies"] for p in parts),
            unsent=sum(p["unsent"] for p in parts),
        )

    @classmethod
    def combine(cls, spec: LoadSpec, parts: Sequence[LoadResult]) -> LoadResult:
        """One result from runs of the same load one after another (``spec``: the whole run)."""
        if not parts:
            raise LoadError("nothing to combine")
        latency, service = new_histogram(), new_histogram()
        errors: Counter[str] = Counter()
        for part in parts:
            latency.add(part.latency)
            service.add(part.service)
            errors.update(part.errors)
        missed = [p.missed_deadlines for p in parts if p.missed_deadlines is not None]
        return cls(
            label=parts[0].label,
            address=parts[0].address,
            spec=spec,
            latency=latency,
            service=service,
            sent=sum(p.sent for p in parts),
            replies=sum(p.replies for p in parts),
            ok=sum(p.ok for p in parts),
            errors=dict(errors),
            missed_deadlines=sum(missed) if spec.mode == "open" else None,
            late_replies=sum(p.late_replies for p in parts),
            unsent=sum(p.unsent for p in parts),
        )


# ---------------------------------------------------------------------------------------------
# One client process
# ---------------------------------------------------------------------------------------------


class _Channel:
    """One DEALER socket speaking the REQ envelope; replies matched to requests by id."""

    def __init__(self, address: str, spec: LoadSpec, client: int) -> None:
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.DEALER)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.connect(address)
        self._spec = spec
        self._client = client
        self.live = spec.payload in ("step", "step-frames")
        prefix = spec.session or ("bench" if self.live else None)
        self._session = None if prefix is None else f"{prefix}-{client}"
        self._steps = 0  # live: steps queued so far, the next step's k
        self._probes = [Probe(spec.probe_at, STEP_DEPTH, spec.probe_radius).to_wire()]
        self._tools = [Tool("sphere", spec.probe_at, STEP_DEPTH, spec.probe_radius).to_wire()]

    def request_bytes(self, number: int) -> bytes:
        """Encode request ``number`` of this client (ids are per socket, so ``number`` is fine)."""
        spec = self._spec
        if self.live:
            frame = spec.payload == "step-frames"
            step = Request(Op.STEP, number, self._session, spec.scene, k=self._steps, frame=frame)
            if spec.press == "tool":
                step.tools = self._tools
            else:
                step.probes = self._probes
            return step.to_wire()
        request = Request(spec.payload, number, self._session, spec.scene)
        if spec.payload == "query":
            # Clients interleave along the time grid, so together they sweep it in order.
            request.t = spec.times[(number * spec.clients + self._client) % len(spec.times)]
        return request.to_wire()

    def send(self, number: int) -> bool:
        """Queue a request without blocking; False when ZeroMQ cannot take it now."""
        try:
            self._socket.send_multipart([b"", self.request_bytes(number)], flags=zmq.NOBLOCK)
        except zmq.Again:
            return False
        self._steps += self.live
        return True

    def session_op(self, op: Op, timeout_s: float) -> None:
        """Open or close this client's live session, waiting for the reply (outside the run)."""
        request = Request(op, _OPEN_ID, self._session, self._spec.scene)
        self._socket.send_multipart([b"", request.to_wire()])
        until = time.perf_counter_ns() + int(timeout_s * 1e9)
        while (got := self.receive(until)) is not None:
            if got[0] == _OPEN_ID:
                if got[2] is not None:
                    raise LoadError(f"{op} of the live session {self._session} failed: {got[2]}")
                return
        raise LoadError(f"no reply to the {op} of the live session {self._session}")

    def receive(self, until_ns: int) -> tuple[int, int, str | None] | None:
        """The next reply before ``until_ns``: (request id, receive time, error code or None)."""
        while True:
            remaining_ms = math.ceil((until_ns - time.perf_counter_ns()) / 1e6)
            if remaining_ms <= 0:
                return None
            if not self._socket.poll(remaining_ms):
                continue  # poll's whole milliseconds ran out a little early: check the clock
            frames = self._socket.recv_multipart(flags=zmq.NOBLOCK)
            received = time.perf_counter_ns()
            request_id, code = peek_reply(frames[-1])
            return request_id, received, code

    def close(self) -> None:
        self._socket.close(linger=0)
        self._context.term()


def _wait_until(due_ns: int) -> None:
    """Sleep, then spin the last ``_SPIN_MARGIN_NS``, so the request leaves on time."""
    remaining = due_ns - time.perf_counter_ns()
    if remaining > _SPIN_MARGIN_NS:
        time.sleep((remaining - _SPIN_MARGIN_NS) / 1e9)
    while time.perf_counter_ns() < due_ns:
        pass


def _open_loop(
    channel: _Channel, spec: LoadSpec, client: int, start_ns: int, progress: _SharedInt
) -> _Tally:
    tally = _Tally()
    period_ns = 1e9 / spec.client_rate
    phase_ns = period_ns * client / spec.clients
    measure_from = start_ns + int(spec.warmup * 1e9)
    stop_ns = measure_from + int(spec.duration * 1e9)
    timeout_ns = int(spec.timeout * 1e9)
    deadline_ns = int((spec.deadline_s or 0.0) * 1e9)
    number = 0
    origin_ns = start_ns + phase_ns
    while (due := int(origin_ns + number * period_ns)) < stop_ns:
        measured = due >= measure_from
        _wait_until(due)
        sent = time.perf_counter_ns()
        if sent >= stop_ns:  # the run is over with requests still due: the server fell behind
            tally.unsent += _count_due(number, origin_ns, period_ns, measure_from, stop_ns)
            break
        tally.sent += measured
        if not channel.send(number):
            if measured:
                tally.errors["send_failed"] += 1
            number += 1
            continue
        reply = _await(channel, number, sent + timeout_ns, tally)
        if measured:
            if reply is None:
                tally.errors["timeout"] += 1
                tally.missed_deadlines += 1
            else:
                received, code = reply
                tally.record(due, sent, received, code)
                tally.missed_deadlines += received - due > deadline_ns
        progress.value += 1
        number += 1
    return tally


def _count_due(first: int, origin_ns: float, period_ns: float, low_ns: int, high_ns: int) -> int:
    """How many requests from number ``first`` on fall due in [low_ns, high_ns)."""
    count, number = 0, first
    while (due := int(origin_ns + number * period_ns)) < high_ns:
        count += due >= low_ns
        number += 1
    return count


def _await(
    channel: _Channel, number: int, until_ns: int, tally: _Tally
) -> tuple[int, str | None] | None:
    """Wait for request ``number``'s reply, dropping late replies to earlier requests.

    An error reply without an id (the server could not read the request) answers the one
    request in flight, as it would on a REQ socket.
    """
    while (got := channel.receive(until_ns)) is not None:
        request_id, received, code = got
        if request_id == number or (request_id == -1 and code is not None):
            return received, code
        tally.late_replies += 1
    return None


def _closed_loop(
    channel: _Channel, spec: LoadSpec, client: int, start_ns: int, progress: _SharedInt
) -> _Tally:
    tally = _Tally()
    measure_from = start_ns + int(spec.warmup * 1e9)
    stop_ns = measure_from + int(spec.duration * 1e9)
    timeout_ns = int(spec.timeout * 1e9)
    pending: dict[int, int] = {}  # request id -> send time
    number = 0

    def send_next() -> None:
        nonlocal number
        now = time.perf_counter_ns()
        if now >= stop_ns:
            return
        if channel.send(number):
            pending[number] = now
            tally.sent += now >= measure_from
        elif now >= measure_from:
            tally.errors["send_failed"] += 1
        number += 1

    _wait_until(start_ns)
    for _ in range(spec.in_flight(client)):
        send_next()
    while pending:
        oldest = min(pending.values())
        got = channel.receive(oldest + timeout_ns)
        if got is None:  # the oldest request timed out: give up on it and replace it
            expired = min(pending, key=pending.__getitem__)
            if pending.pop(expired) >= measure_from:
                tally.errors["timeout"] += 1
            send_next()
            continue
        request_id, received, code = got
        sent = pending.pop(request_id, None)
        if sent is None:
            tally.late_replies += 1
            continue
        if sent >= measure_from:
            tally.record(sent, sent, received, code)
        progress.value += 1
        send_next()
    return tally


def _client_main(
    address: str,
    spec: LoadSpec,
    client: int,
    ready: multiprocessing.queues.Queue[Any],
    go: Any,
    start_ns: _SharedInt,
    progress: _SharedInt,
    results: multiprocessing.queues.Queue[Any],
) -> None:
    """Entry point of one client process: connect, wait for the common start, run, report."""
    channel = _Channel(address, spec, client)
    try:
        if channel.live:
            channel.session_op(Op.OPEN, _STARTUP_TIMEOUT_S)
        ready.put(client)
        if not go.wait(_STARTUP_TIMEOUT_S):
            results.put((client, None, "never told to start"))
            return
        loop = _open_loop if spec.mode == "open" else _closed_loop
        tally = loop(channel, spec, client, start_ns.value, progress)
        if channel.live:
            channel.session_op(Op.CLOSE, spec.timeout * 5)
        results.put((client, tally.to_wire(), None))
    except Exception as exc:  # reported to the parent, which fails the run with it
        results.put((client, None, f"{type(exc).__name__}: {exc}"))
    finally:
        channel.close()


# ---------------------------------------------------------------------------------------------
# The parent: start clients, show progress, merge
# ---------------------------------------------------------------------------------------------

ProgressHook = Callable[[float, int], None]
"""Called about 5 times a second with (seconds elapsed since start, replies so far)."""


def run_load(
    address: str, spec: LoadSpec, label: str = "server", on_progress: ProgressHook | None = None
) -> LoadResult:
    """Run ``spec`` against ``address`` from ``spec.clients`` processes and merge the results.

    Raises:
        LoadError: A client process failed to start, crashed, or did not finish in time.
    """
    context = multiprocessing.get_context("spawn")  # no inherited ZeroMQ state in the children
    ready: multiprocessing.queues.Queue[Any] = context.Queue()
    results: multiprocessing.queues.Queue[Any] = context.Queue()
    go = context.Event()
    start_ns = context.RawValue("q", 0)
    counters = [context.RawValue("q", 0) for _ in range(spec.clients)]
    processes = [
        context.Process(
            target=_client_main,
            args=(address, spec, i, ready, go, start_ns, counters[i], results),
            name=f"membrane-bench-{label}-{i}",
            daemon=True,
        )
        for i in range(spec.clients)
    ]
    for process in processes:
        process.start()
    try:
        _wait_ready(ready, processes)
        start_ns.value = time.perf_counter_ns() + _START_DELAY_NS
        go.set()
        parts = _collect(results, spec, start_ns.value, counters, on_progress)
    finally:
        for process in processes:
            process.join(timeout=5.0)
            if process.is_alive():
                process.kill()
                process.join(timeout=5.0)
    return LoadResult.merge(label, address, spec, parts)


def _wait_ready(
    ready: multiprocessing.queues.Queue[Any],
    processes: Sequence[multiprocessing.process.BaseProcess],
) -> None:
    give_up = time.monotonic() + _STARTUP_TIMEOUT_S
    waiting = len(processes)
    while waiting:
        try:
            ready.get(timeout=0.1)
            waiting -= 1
        except queue.Empty:
            if not all(p.is_alive() for p in processes) or time.monotonic() > give_up:
                raise LoadError("client processes failed to start") from None


def _collect(
    results: multiprocessing.queues.Queue[Any],
    spec: LoadSpec,
    start_ns: int,
    counters: Sequence[_SharedInt],
    on_progress: ProgressHook | None,
) -> list[dict[str, Any]]:
    run_s = _START_DELAY_NS / 1e9 + spec.warmup + spec.duration
    # A client stops sending at the end and waits at most `timeout` per pending request after.
    give_up = time.monotonic() + run_s + spec.timeout * (spec.concurrency + 2) + 30.0
    parts: dict[int, dict[str, Any]] = {}
    while len(parts) < spec.clients:
        try:
            client, tally, failure = results.get(timeout=0.2)
        except queue.Empty:
            if time.monotonic() > give_up:
                raise LoadError("client processes did not finish in time") from None
        else:
            if failure is not None:
                raise LoadError(f"client {client} failed: {failure}")
            parts[client] = tally
        if on_progress is not None:
            elapsed = (time.perf_counter_ns() - start_ns) / 1e9
            on_progress(max(elapsed, 0.0), sum(int(c.value) for c in counters))
    return [parts[i] for i in sorted(parts)]
