"""Server-side counters and latency percentiles (the ``stats`` op).

Latency is measured from receiving a request to handing its reply to ZeroMQ, kept for the last
``window`` requests in a ring buffer. Percentiles are computed when asked for, at most once per
``percentile_interval`` seconds: a flood of ``stats`` requests must not cost a sort of the whole
window each (about a millisecond), which would delay everyone else's replies.
"""

from __future__ import annotations

import math
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np

from membrane_server.log_output import log_counts

__all__ = ["Stats"]


class Stats:
    """Counts by op, error code and scene; distinct sessions; a window of latencies.

    Args:
        window: How many of the latest latencies the percentiles cover.
        max_sessions: How many session ids are remembered (least recently seen are forgotten).
        percentile_interval: Seconds a computed set of percentiles is reused for.
    """

    def __init__(
        self, window: int = 100_000, max_sessions: int = 10_000, percentile_interval: float = 1.0
    ) -> None:
        self.started = time.monotonic()
        self.requests = 0
        self.ops: Counter[str] = Counter()
        self.errors: Counter[str] = Counter()
        self.scenes: Counter[str] = Counter()
        self._sessions: OrderedDict[str, None] = OrderedDict()
        self._max_sessions = max_sessions
        self._latencies = np.zeros(window, dtype=np.float64)
        self._latency_count = 0
        self._percentile_interval = percentile_interval
        self._percentiles: dict[str, float | int] | None = None
        self._percentiles_at = -math.inf
        # Replies ZeroMQ would not take, by reason ("peer_not_reading": its queue is full;
        # "peer_gone": it disconnected before its reply was ready).
        self.dropped: Counter[str] = Counter()
        # Requests whose handling raised out of the dispatcher (a bug; each is logged).
        self.failures = 0
        self._figures: dict[str, Callable[[], Any]] = {}

    def add_figures(self, name: str, figures: Callable[[], Any]) -> None:
        """Add ``name`` to the snapshot, its value ``figures()`` when one is taken (the server's
        peers, memory and reloads)."""
        self._figures[name] = figures

    def record(
        self,
        seconds: float,
        op: str | None = None,
        error: str | None = None,
        scene: str | None = None,
        session: str | None = None,
    ) -> None:
        """Account for one answered request."""
        self.requests += 1
        self._latencies[self._latency_count % self._latencies.size] = seconds
        self._latency_count += 1
        if op is not None:
            self.ops[op] += 1
        if error is not None:
            self.errors[error] += 1
        elif scene is not None and op == "query":
            self.scenes[scene] += 1
        if session is not None:
            self._sessions[session] = None
            self._sessions.move_to_end(session)
            if len(self._sessions) > self._max_sessions:
                self._sessions.popitem(last=False)

    def record_dropped(self, reason: str) -> None:
        """Account for a reply that could not be handed to ZeroMQ."""
        self.dropped[reason] += 1

    @property
    def sessions(self) -> int:
        """Distinct session ids remembered."""
        return len(self._sessions)

    def recent_latency_us(self) -> dict[str, float | int]:
        """``latency_us()`` computed at most once per ``percentile_interval`` (what the ``stats``
        op answers; ``age_s`` says how old the figures are)."""
        now = time.monotonic()
        if self._percentiles is None or now - self._percentiles_at >= self._percentile_interval:
            self._percentiles = self.latency_us()
            self._percentiles_at = now
        return {**self._percentiles, "age_s": now - self._percentiles_at}

    def latency_us(self) -> dict[str, float | int]:
        """Percentiles of the latency window, in microseconds, computed now."""
        count = min(self._latency_count, self._latencies.size)
        if count == 0:
            return {"count": 0, "window": int(self._latencies.size)}
        micros = self._latencies[:count] * 1e6
        p50, p90, p99, p999 = np.percentile(micros, [50.0, 90.0, 99.0, 99.9])
        return {
            "count": count,
            "window": int(self._latencies.size),
            "p50": float(p50),
            "p90": float(p90),
            "p99": float(p99),
            "p999": float(p999),
            "max": float(micros.max()),
            "mean": float(micros.mean()),
        }

    def snapshot(self) -> dict[str, Any]:
        """Everything, as plain data for the ``stats`` reply."""
        return {
            "uptime_s": time.monotonic() - self.started,
            "requests": self.requests,
            "errors": dict(self.errors),
            "ops": dict(self.ops),
            "scenes": dict(self.scenes),
            "sessions": self.sessions,
            "latency_us": self.recent_latency_us(),
            "dropped_replies": dict(self.dropped),
            "failures": self.failures,
            "log": log_counts(),
            **{name: figures() for name, figures in self._figures.items()},
        }
