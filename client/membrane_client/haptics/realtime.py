"""The servo thread's scheduling: a fixed real-time priority where the OS grants one.

A thread that sleeps to each deadline competes, when it wakes, with every runnable thread on
its core at the same priority: the network side, the server, anything else the machine runs.
Under Linux's normal policy it waits its turn (measured: one tick in fifty missed at 1 kHz with
a second process keeping one core of two busy); under ``SCHED_FIFO`` it preempts them as soon
as it wakes, as haptic SDKs run their servo threads. Linux grants the policy to root, to a
process with ``CAP_SYS_NICE``, or within an ``rtprio`` limit (``/etc/security/limits.conf``:
``@haptics - rtprio 50``); elsewhere the thread stays at normal priority and says so. The
kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % of each second by
default) keeps a runaway callback from locking the core.
"""

from __future__ import annotations

import os

__all__ = ["DEFAULT_PRIORITY", "make_realtime"]

# Below the kernel's threaded interrupt handlers (50), above every normal thread.
DEFAULT_PRIORITY = 40


def make_realtime(priority: int | None = DEFAULT_PRIORITY) -> bool:
    """Move the calling thread (only it: Linux schedules threads) to ``SCHED_FIFO`` at
    ``priority`` (1 to 99); None: leave it. True when it runs at that priority now."""
    if priority is None or not hasattr(os, "sched_setscheduler"):
        return False
    if not 1 <= priority <= 99:
        raise ValueError(f"a SCHED_FIFO priority is 1 to 99, got {priority!r}")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:  # not granted here (PermissionError): normal priority, reported
        return False
    return True
