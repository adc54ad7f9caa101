"""A haptic loop that must not notice an attack: a live session stepped at 200 Hz, in a thread.

``LiveGoodClient`` opens its own session (a real ``membrane_client.Client`` and ``Session``) on a
live scene and takes one step every 5 ms, with a probe pressing the patch, a frame every 10th
step. Each step has a deadline, its slot's end: a reply later than that is a miss, and so is a
slot skipped because the previous reply came too late. The run is split in phases on the same
client and server: first undisturbed (``measure``), then during the attack (``begin``), and
undisturbed again after it, so that ``check_against_undisturbed`` compares the client with
itself on the same machine, loaded as it was around the attack: no failure, and a miss rate at
most 5 percentage points above the undisturbed one (the worse of the two, when measured after
too: a shared machine's load changes within a test).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import pytest
from reporting import print_past_capture

from membrane_client import Client
from membrane_client.errors import MembraneError
from membrane_client.session import Probe, Session

GOOD_LIVE_SCENE = "membrane-live"
PERIOD_S = 0.005
FRAME_EVERY = 10
# Misses the attack may add to the undisturbed run, in percentage points.
EXTRA_MISS_POINTS = 5.0
_PROBE = Probe((0.5, 0.5), depth=0.002, radius=0.05)


@dataclass
class LiveRun:
    """One phase of the loop: slots, steps answered, misses, failures, round trips."""

    label: str
    slots: int = 0
    steps: int = 0
    misses: int = 0
    failures: list[str] = field(default_factory=list)
    round_trips: list[float] = field(default_factory=list)

    @property
    def miss_rate(self) -> float:
        """Percentage of slots whose step was not answered within its period."""
        return 100.0 * self.misses / self.slots if self.slots else 0.0

    def percentile_us(self, q: float) -> float:
        """A round-trip percentile in microseconds (NaN before any step)."""
        if not self.round_trips:
            return math.nan
        ordered = sorted(self.round_trips)
        return ordered[min(len(ordered) - 1, int(q / 100.0 * len(ordered)))] * 1e6

    def line(self) -> str:
        return (
            f"{self.label}: {self.steps} steps in {self.slots} slots, {self.misses} missed "
            f"({self.miss_rate:.1f}%), {len(self.failures)} failures, round trip p50 "
            f"{self.percentile_us(50):.0f} us, p99 {self.percentile_us(99):.0f} us"
        )


class LiveGoodClient:
    """A session stepped every ``period`` seconds in a thread until ``stop``.

    Args:
        address: The server.
        scene: A live scene the server hosts.
        timeout: Per-request timeout; a step unanswered after one re-send is a failure.
        socket_options: For the client's sockets (CurveZMQ keys).
    """

    def __init__(
        self,
        address: str,
        scene: str = GOOD_LIVE_SCENE,
        *,
        period: float = PERIOD_S,
        frame_every: int = FRAME_EVERY,
        timeout: float = 1.0,
        socket_options: Mapping[int, int | bytes] | None = None,
    ) -> None:
        self.address, self.scene, self.period = address, scene, period
        self.frame_every, self.timeout = frame_every, timeout
        self.socket_options = dict(socket_options or {})
        self.runs: list[LiveRun] = [LiveRun("starting")]
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._opened = threading.Event()
        self._thread = threading.Thread(target=self._run, name="live-good-client", daemon=True)

    @property
    def current(self) -> LiveRun:
        return self.runs[-1]

    def start(self) -> LiveGoodClient:
        """Open the session and start stepping (raises when the session cannot open)."""
        self._thread.start()
        if not self._opened.wait(30.0) or self.current.failures:
            self.stop()
            raise AssertionError(f"the good client could not open its session: {self.runs}")
        return self

    def begin(self, label: str) -> LiveRun:
        """End the current phase and start ``label``; returns the phase just ended."""
        with self._lock:
            ended = self.runs[-1]
            self.runs.append(LiveRun(label))
        return ended

    def measure(self, seconds: float, label: str = "undisturbed") -> LiveRun:
        """Step ``seconds`` in a phase of its own (the undisturbed run) and return it."""
        self.begin(label)
        time.sleep(seconds)
        return self.begin("between")

    def stop(self) -> LiveRun:
        """Stop stepping; returns the last phase."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(30.0)
        return self.current

    def _run(self) -> None:
        try:
            client = Client(
                self.address, timeout=self.timeout, retries=1, socket_options=self.socket_options
            )
            with client, client.session(self.scene) as session:
                self._opened.set()
                self._step_forever(session)
        except MembraneError as exc:  # opening or closing failed
            self.current.failures.append(f"session: {type(exc).__name__}: {exc}")
        finally:
            self._opened.set()

    def _step_forever(self, session: Session) -> None:
        slot_start = time.perf_counter()
        while not self._stop.is_set():
            deadline = slot_start + self.period
            k = session.k
            sent = time.perf_counter()
            failure = None
            try:
                result = session.step(probes=[_PROBE], frame=k % self.frame_every == 0)
                if result.k != k + 1 or not math.isfinite(result.probes[0].force):
                    failure = f"step {k}: answered k {result.k}, force {result.probes[0].force}"
            except MembraneError as exc:
                failure = f"step {k}: {type(exc).__name__}: {exc}"
            answered = time.perf_counter()
            # Slots that passed while waiting are missed too (no coordinated omission).
            skipped = max(0, int((answered - deadline) / self.period))
            with self._lock:
                run = self.runs[-1]
                run.slots += 1 + skipped
                run.misses += skipped + (failure is not None or answered > deadline)
                if failure is None:
                    run.steps += 1
                    run.round_trips.append(answered - sent)
                else:
                    run.failures.append(failure)
            if failure is not None:
                _resync(session)
            slot_start = deadline + skipped * self.period
            pause = slot_start - time.perf_counter()
            if pause > 0:
                time.sleep(pause)


def _resync(session: Session) -> None:
    """After a failure, take the session's step count from the server."""
    with contextlib.suppress(MembraneError):
        session.k = session.frame().k


def check_against_undisturbed(
    request: pytest.FixtureRequest,
    attack: str,
    undisturbed: LiveRun,
    during: LiveRun,
    after: LiveRun | None = None,
    extra_points: float = EXTRA_MISS_POINTS,
) -> None:
    """Print the runs past pytest's capture, then assert: the good client ran during the
    attack, failed never, and missed at most ``extra_points`` more of its deadlines (in
    percentage points) than undisturbed (the worse of before and ``after``)."""
    runs = [undisturbed, during] + ([after] if after is not None else [])
    figures = "; ".join(run.line() for run in runs)
    print_past_capture(request, f"\n{attack}: 200 Hz good client: {figures}")
    assert all(run.steps > 0 for run in runs), [run.line() for run in runs]
    for run in runs:
        assert run.failures == [], (run.label, run.failures[:5])
    reference = max(undisturbed.miss_rate, after.miss_rate if after is not None else 0.0)
    assert during.miss_rate <= reference + extra_points, [run.line() for run in runs]
