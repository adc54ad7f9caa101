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
"""

from __future__ import annotations

import math
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from membrane_client.errors import UserError
from membrane_client.haptics.channel import Channel, ContactRecord, State
from membrane_client.haptics.coupling import Contact, Coupling, Proxy, couple

__all__ = ["HapticLoop", "HapticReport", "Tick"]

_START_TIMEOUT_S = 20.0  # the network process's imports, connection and session open
_STOP_TIMEOUT_S = 5.0
_STALE_STEPS = 3.0  # a contact older than this many of the scene's steps is stale
_RECENT_TICKS = 2**20  # the ticks the report's percentiles are over: the last 17 min at 1 kHz


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
    the per-tick computation's percentiles over the last 2^20 ticks (reading the contact,
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
    error: str | None = None


class _Recent:
    """The last ``size`` values of a per-tick figure (bounded memory on a run of any length)."""

    def __init__(self, size: int = _RECENT_TICKS) -> None:
        self._values = np.empty(size)
        self._count = 0

    def append(self, value: float) -> None:
        self._values[self._count % self._values.size] = value
        self._count += 1

    def percentile(self, q: float) -> float:
        held = self._values[: min(self._count, self._values.size)]
        return float(np.percentile(held, q)) if held.size else math.nan


@dataclass
class _Counters:
    ticks: int = 0
    missed: int = 0
    stale: int = 0
    compute: _Recent = field(default_factory=_Recent)
    late: _Recent = field(default_factory=_Recent)


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
    ) -> None:
        if not (math.isfinite(rate_hz) and 1.0 <= rate_hz <= 100_000.0):
            raise UserError(f"rate_hz must be in [1, 100000], got {rate_hz!r}")
        if not (math.isfinite(radius) and radius >= 0.0):
            raise UserError(f"radius must be >= 0, got {radius!r}")
        self.address, self.scene, self.radius = address, scene, float(radius)
        self.period = 1.0 / rate_hz
        self.coupling = coupling or Coupling()
        self._position, self._render, self._timeout = position, render, timeout
        self._counters = _Counters()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._process: subprocess.Popen[str] | None = None
        self._channel: Channel | None = None
        self._record: ContactRecord | None = None
        self._error: str | None = None
        self.latest: Tick | None = None
        self.contact = Contact(0.0, math.nan)  # the contact the last tick rendered from

    def start(self) -> HapticLoop:
        """Start the network process, wait for its session, then the servo thread.

        Raises:
            UserError: the network side could not open the session (its one-line reason).
        """
        dims = len(self._position()) - 1
        if dims not in (1, 2):
            raise UserError(f"position() gives (x, [y,] depth): 2 or 3 numbers, got {dims + 1}")
        self._channel = channel = Channel.create()
        command = [sys.executable, "-m", "membrane_client.haptics.network"]
        command += ["--address", self.address, "--scene", self.scene]
        command += ["--channel", str(channel.path), "--radius", repr(self.radius)]
        command += ["--dims", str(dims), "--timeout", repr(self._timeout)]
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
        self._thread = threading.Thread(target=self._serve, args=(dims,), daemon=True)
        self._thread.start()
        return self

    def stop(self) -> HapticReport:
        """Stop the servo thread and the network process; what they did."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(_STOP_TIMEOUT_S)
        self._shutdown()
        return self.report()

    def report(self) -> HapticReport:
        counters, record = self._counters, self._record
        p50, p99 = (1e6 * counters.compute.percentile(q) for q in (50, 99))
        late = 1e6 * counters.late.percentile(99)
        steps, skipped, lost = (
            (0, 0, 0) if record is None else (record.steps, record.skipped, record.lost)
        )
        return HapticReport(
            counters.ticks, counters.missed, float(p50), float(p99), late, counters.stale,
            steps, skipped, lost, self._error,
        )  # fmt: skip

    def __enter__(self) -> HapticLoop:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _serve(self, dims: int) -> None:
        assert self._channel is not None
        channel, period, counters = self._channel, self.period, self._counters
        proxy, contact = Proxy(), Contact(0.0, math.nan)
        stale_after = _STALE_STEPS * max(channel.dt, period)
        start = time.monotonic()
        deadline, seen = start, 0.0
        k = damper = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now < deadline:
                time.sleep(deadline - now)
                now = time.monotonic()
            counters.late.append(now - deadline)
            late = int((now - deadline) / period)
            if late:  # whole periods lost: count them and render the present
                counters.missed += late
                deadline += late * period
            *at, depth = self._position()
            began = time.perf_counter()
            version = channel.contact_version
            if version != seen:  # a new record (or one being written: read_contact tells)
                record = channel.read_contact()
                if record is not None:
                    seen, self._record = version, record
                    contact = Contact.ahead(
                        record.free, record.compliance, record.static_compliance, record.k
                    )
                    k, b = self.coupling.gains(contact, period)
                    damper = b / period
            if self._record is None:  # nothing seen yet: hold the tip at the rest surface
                proxy = Proxy(min(float(depth), 0.0), float(depth), 0.0)
            elif not contact.touchable:  # outside the domain: nothing to press
                proxy = Proxy(float(depth), float(depth), 0.0)
            else:
                proxy = couple(float(depth), proxy, contact, k, damper)
            self.contact = contact
            channel.write_proxy(tuple(float(x) for x in at), proxy.depth, proxy.force, contact.k)
            counters.compute.append(time.perf_counter() - began)
            age = math.inf if self._record is None else now - self._record.received
            stale = age > stale_after
            counters.stale += stale
            counters.ticks += 1
            self.latest = tick = Tick(
                deadline - start, float(depth), proxy.depth, proxy.force, contact.k, age, stale
            )
            if self._render is not None:
                self._render(tick)
            deadline += period

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
