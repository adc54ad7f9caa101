"""The servo thread's bookkeeping: histogram percentiles against numpy's on the same values,
and the scheduling request's answers."""

from __future__ import annotations

import math
import os
import threading

import numpy as np
import pytest

from membrane_client.haptics.histogram import Histogram
from membrane_client.haptics.realtime import make_realtime


def test_percentiles_are_numpys_to_one_bin() -> None:
    values = np.random.default_rng(7).lognormal(np.log(20e-6), 0.6, 50_000)
    histogram = Histogram()
    for value in values:
        histogram.add(float(value))
    assert histogram.count == values.size
    for q in (1, 50, 99, 99.9):
        exact = float(np.percentile(values, q))
        # a bin's upper edge: within one bin (1 us) of the exact value
        assert histogram.percentile(q) == pytest.approx(exact, abs=1e-6)


def test_beyond_the_limit_the_largest_value_is_reported() -> None:
    histogram = Histogram(limit=1e-3)
    for value in (5e-6, 6e-6, 0.25):
        histogram.add(value)
    assert histogram.percentile(100) == 0.25 and histogram.percentile(1) == pytest.approx(6e-6)


def test_an_empty_histogram_has_no_percentiles_and_bad_bins_are_refused() -> None:
    assert math.isnan(Histogram().percentile(50))
    with pytest.raises(ValueError, match="resolution < limit"):
        Histogram(resolution=1e-3, limit=1e-4)


def test_a_realtime_request_moves_only_its_own_thread() -> None:
    if not hasattr(os, "sched_getscheduler"):
        pytest.skip("no POSIX scheduling on this platform")
    before = os.sched_getscheduler(0)
    answers: list[tuple[bool, int]] = []

    def ask() -> None:
        granted = make_realtime(10)
        answers.append((granted, os.sched_getscheduler(0)))

    thread = threading.Thread(target=ask)
    thread.start()
    thread.join()
    granted, policy = answers[0]
    assert policy == (os.SCHED_FIFO if granted else before)
    assert os.sched_getscheduler(0) == before  # the calling thread is untouched
    assert make_realtime(None) is False
    with pytest.raises(ValueError, match="1 to 99"):
        make_realtime(0)
