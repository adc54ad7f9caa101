"""The haptic loop: a force for the device every tick, whatever the network does.

```python
loop = HapticLoop(address, "skin-patch", position=device.tip, render=device.apply, radius=0.0)
with loop:                      # starts the network process and the servo thread
    ...                         # the device is rendered at 1 kHz until the block ends
print(loop.report())
```

Each tick (``rate_hz``, in a thread of its own) reads the device's position (``position()``:
the tip's coordinates in the scene's frame, then its depth into the tissue along the press
axis, in the scene's units), couples it to the tool proxy (``coupling``) through the contact
the last server step sent, writes the proxy's position for the network side and hands the
force to ``render``; the network side applies that force to the tissue at its next step. The
contact is the step's look-ahead: the next step's free displacement and one-step compliance
under the tip, so the proxy's depth is where that force leaves the tissue at the end of the
next step (the constraint-based rendering of SOFA's multirate haptics: the tissue at the
scene's rate, the contact at the device's). The network side
(``network``) runs in another process; while it is late (a stalled server) the loop keeps
rendering from the last contact, moving with the device by the sent compliance, and says so
(``Tick.stale``).

The servo thread runs at a ``SCHED_FIFO`` priority where the OS grants one (``realtime``), wakes
``lead`` ahead of each deadline to take the newest contact and warm the tick, keeps its timings
in fixed histograms, and ``start`` freezes the garbage collector's old objects until ``stop``
(docs/HAPTICS.md, "The servo thread", has the measurements behind each).
"""

from __future__ import annotations

import gc
import math
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from membrane_client.errors import UserError
from membrane_client.haptics.channel import Channel, ContactRecord, State
from membrane_client.haptics.coupling import Contact, Coupling, balance
from membrane_client.haptics.histogram import Histogram
from membrane_client.haptics.realtime import DEFAULT_PRIORITY, make_realtime

__all__ = ["HapticLoop", "HapticReport", "Tick"]

_START_TIMEOUT_S = 20.0  # the network process's imports, connection and session open
_STOP_TIMEOUT_S = 5.0
_STALE_STEPS = 3.0  # a contact older than this many of the scene's steps is stale
_LEAD_S = 1e-4  # the longest wake-up ahead of a deadline by default (a quarter period below)


class Tick(NamedTuple):
    """One tick of the loop, as ``render`` gets it.

    Attributes:
        t: seconds since the loop started (its deadline, not when it ran).
        device: the device's depth; proxy: the proxy's (scene units).
        force: the force to render (>= 0, pushing the device back along +axis).
        k: the step count the contact came from (0 before the first reply).
        age: seconds since that contact arrived (inf before the first).
        stale: the contact is older than three of the scene's steps: the network is late.
    """

    t: float
    device: float
    proxy: float
    force: float
    k: int
    age: float
    stale: bool


@dataclass(frozen=True)
class HapticReport:
    """What a loop did: ticks, deadlines missed (a tick that began a period or more late),
    the per-tick computation's percentiles over every tick, to 1 us (reading the contact,
    coupling, writing the proxy; not the user's ``position`` and ``render``), ticks rendered
    from a stale contact, and the network side's steps taken, skipped and lost, and its error
    if it stopped on one."""

    ticks: int
    missed: int
    compute_p50_us: float
    compute_p99_us: float
    late_p99_us: float  # how late a tick began after its deadline, p99
    stale_ticks: int
    steps: int
    skipped: int
    lost: int
    realtime: bool = False  # the servo thread ran at its SCHED_FIFO priority
    error: str | None = None


@dataclass
class _Counters:
    ticks: int = 0
    missed: int = 0
    stale: int = 0
    compute: Histogram = field(default_factory=Histogram)
    late: Histogram = field(default_factory=Histogram)


class _Renderer:
    """A tick's computation, in two parts: ``prepare`` when the thread wakes (the newest
    contact from the channel, then a dry run of the tick), ``tick`` at the deadline (the
    coupling's balance from the device's depth, the proxy into the channel). Plain numbers
    throughout: after a sleep every Python operation costs several times its warm price, so
    the dry run brings the tick's code and data back into cache before the device is read."""

    def __init__(self, channel: Channel | None, coupling: Coupling, period: float) -> None:
        self.channel, self.coupling, self.period = channel, coupling, period
        self.record: ContactRecord | None = None
        self.contact = Contact(0.0, math.nan)
        self.seen, self.touchable = 0.0, False
        self.k = self.damper = 0.0
        # the last tick's: the device's and proxy's depths, the force, the tip's centre, and
        # the step its contact came from (what the network side waits on: module docstring)
        self.device = self.depth = self.force = 0.0
        self.x = self.y = 0.0
        self.step = -1

    def prepare(self) -> None:
        channel = self.channel
        assert channel is not None
        version = channel.contact_version
        if version != self.seen:  # a new record (or one being written: read_contact tells)
            self._take(channel, version)
        if self.step >= 0:  # the dry run: the last tick's numbers, the same record again
            self._balance(self.device)
            channel.write_proxy(self.x, self.y, self.depth, self.force, self.step)

    def tick(self, x: float, y: float, device: float) -> None:
        assert self.channel is not None
        depth, force = self._balance(device)
        self.device, self.depth, self.force = device, depth, force
        self.x, self.y, self.step = x, y, self.contact.k
        self.channel.write_proxy(x, y, depth, force, self.step)

    def _balance(self, device: float) -> tuple[float, float]:
        if self.record is None:  # nothing seen yet: hold the tip at the rest surface
            return min(device, 0.0), 0.0
        if not self.touchable:  # outside the domain: nothing to press
            return device, 0.0
        contact = self.contact
        return balance(
            device, self.device, self.depth, contact.free, contact.compliance,
            self.k, self.damper,
        )  # fmt: skip

    def _take(self, channel: Channel, version: float) -> None:
        record = channel.read_contact()
        if record is None:
            return
        self.seen, self.record = version, record
        self.contact = contact = Contact.ahead(
            record.free, record.compliance, record.static_compliance, record.k
        )
        self.touchable = contact.touchable
        self.k, b = self.coupling.gains(contact, self.period)
        self.damper = b / self.period


class HapticLoop:
    """A servo loop rendering a live session's contact (module docstring).

    Args:
        address: the server's endpoint.
        scene: a live scene.
        position: the device's tip, (x, [y,] depth), each tick.
        rate_hz: the servo rate (1 kHz by default; 5 kHz and more run too).
        radius: the tip's footprint (the probe's radius; 0 on strings and plates).
        coupling: the virtual coupling (``Coupling()``: the defaults its docstring gives).
        render: called with each ``Tick`` (the device's force); None: only ``latest``.
        timeout: the network side's wait for a reply before a retry (s).
        priority: the servo thread's ``SCHED_FIFO`` priority where the OS grants it
            (``realtime``); None: normal priority.
        lead: how long before each deadline the thread wakes to take the newest contact and
            warm the tick, then spins to the deadline (s); None: a quarter period, at most
            100 us; 0: wake at the deadline.
    """

    def __init__(
        self,
        address: str,
        scene: str,
        position: Callable[[], Sequence[float]],
        *,
        rate_hz: float = 1000.0,
        radius: float = 0.0,
        coupling: Coupling | None = None,
        render: Callable[[Tick], None] | None = None,
        timeout: float = 0.25,
        priority: int | None = DEFAULT_PRIORITY,
        lead: float | None = None,
    ) -> None:
        if priority is not None and not 1 <= priority <= 99:
            raise UserError(f"priority must be a SCHED_FIFO priority 1 to 99 or None: {priority!r}")
        if not (math.isfinite(rate_hz) and 1.0 <= rate_hz <= 100_000.0):
            raise UserError(f"rate_hz must be in [1, 100000], got {rate_hz!r}")
        if not (math.isfinite(radius) and radius >= 0.0):
            raise UserError(f"radius must be >= 0, got {radius!r}")
        self.address, self.scene, self.radius = address, scene, float(radius)
        self.period = 1.0 / rate_hz
        if lead is not None and not (math.isfinite(lead) and 0.0 <= lead < self.period):
            raise UserError(f"lead must be in [0, the period {self.period:g} s), got {lead!r}")
        self.lead = min(_LEAD_S, self.period / 4) if lead is None else float(lead)
        self.coupling = coupling or Coupling()
        self._position, self._render, self._timeout = position, render, timeout
        self._counters = _Counters()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._process: subprocess.Popen[str] | None = None
        self._channel: Channel | None = None
        self._renderer = _Renderer(None, self.coupling, self.period)
        self._priority, self._realtime, self._froze = priority, False, False
        self._error: str | None = None
        self.latest: Tick | None = None

    def start(self) -> HapticLoop:
        """Start the network process, wait for its session, then the servo thread.

        Raises:
            UserError: the network side could not open the session (its one-line reason).
        """
        *at, _ = self._position()
        dims = len(at)
        if dims not in (1, 2):
            raise UserError(f"position() gives (x, [y,] depth): 2 or 3 numbers, got {dims + 1}")
        self._channel = channel = Channel.create()
        command = [sys.executable, "-m", "membrane_client.haptics.network"]
        command += ["--address", self.address, "--scene", self.scene]
        command += ["--channel", str(channel.path), "--radius", repr(self.radius)]
        command += ["--dims", str(dims), "--timeout", repr(self._timeout)]
        command += ["--at", *(repr(float(x)) for x in at)]
        self._process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + _START_TIMEOUT_S
        while channel.state is State.STARTING and self._process.poll() is None:
            if time.monotonic() > deadline:
                self._shutdown()
                raise UserError(
                    f"the haptic loop's network side did not start in {_START_TIMEOUT_S:g} s"
                )
            time.sleep(0.005)
        if channel.state is not State.RUNNING:
            reason = self._network_error() or "the network side exited"
            self._shutdown()
            raise UserError(reason)
        self._froze = gc.get_freeze_count() == 0
        if self._froze:  # a collection in the servo thread scans only what is made from now
            gc.freeze()
        self._thread = threading.Thread(target=self._serve, args=(dims,), daemon=True)
        self._thread.start()
        return self

    def stop(self) -> HapticReport:
        """Stop the servo thread and the network process; what they did."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(_STOP_TIMEOUT_S)
        if self._froze:
            gc.unfreeze()
            self._froze = False
        self._shutdown()
        return self.report()

    @property
    def contact(self) -> Contact:
        """The contact the last tick rendered from."""
        return self._renderer.contact

    def report(self) -> HapticReport:
        counters, record = self._counters, self._renderer.record
        p50, p99 = (1e6 * counters.compute.percentile(q) for q in (50, 99))
        late = 1e6 * counters.late.percentile(99)
        steps, skipped, lost = (
            (0, 0, 0) if record is None else (record.steps, record.skipped, record.lost)
        )
        return HapticReport(
            counters.ticks, counters.missed, float(p50), float(p99), late, counters.stale,
            steps, skipped, lost, self._realtime, self._error,
        )  # fmt: skip

    def __enter__(self) -> HapticLoop:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _serve(self, dims: int) -> None:
        assert self._channel is not None
        self._realtime = make_realtime(self._priority)
        channel, period, counters = self._channel, self.period, self._counters
        self._renderer = renderer = _Renderer(channel, self.coupling, period)
        stale_after = _STALE_STEPS * max(channel.dt, period)
        lead = self.lead
        start = deadline = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now < deadline - lead:
                time.sleep(deadline - lead - now)
            renderer.prepare()  # the newest contact, and the tick warmed
            while (now := time.monotonic()) < deadline:
                pass  # the last microseconds, on a warm core
            counters.late.add(now - deadline)
            late = int((now - deadline) / period)
            if late:  # whole periods lost: count them and render the present
                counters.missed += late
                deadline += late * period
            *at, depth = self._position()
            x, y, device = float(at[0]), float(at[-1]) if dims == 2 else 0.0, float(depth)
            began = time.perf_counter()
            renderer.tick(x, y, device)
            counters.compute.add(time.perf_counter() - began)
            self._publish(deadline - start, now, device, renderer, stale_after)
            deadline += period

    def _publish(
        self, t: float, now: float, device: float, renderer: _Renderer, stale_after: float
    ) -> None:
        """The tick as ``render`` and ``latest`` get it."""
        record, counters = renderer.record, self._counters
        age = math.inf if record is None else now - record.received
        stale = age > stale_after
        counters.stale += stale
        counters.ticks += 1
        tick = Tick(t, device, renderer.depth, renderer.force, renderer.contact.k, age, stale)
        self.latest = tick
        if self._render is not None:
            self._render(tick)

    def _shutdown(self) -> None:
        if self._channel is not None:
            self._channel.request_stop()
        if self._process is not None:
            try:
                self._process.wait(_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
            self._error = self._error or self._network_error()
            self._process = None
        if self._channel is not None:
            self._channel.close()
            self._channel = None

    def _network_error(self) -> str | None:
        process = self._process
        if process is None or process.poll() is None or process.stderr is None:
            return None
        lines = [line.strip() for line in process.stderr.read().splitlines() if line.strip()]
        return lines[-1] if lines else None
