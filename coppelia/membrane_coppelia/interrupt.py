"""SIGINT and SIGTERM end a run cleanly: the simulation is stopped, stepping released.

A stepping client that stops talking holds CoppeliaSim's simulation until the remote API add-on
forgets it (its remote timeout). So Ctrl-C, or a service manager's SIGTERM, must not just kill
the adapter: :func:`interrupt_on` turns the first of these signals into :class:`Interrupted`,
raised where the main thread is (in the middle of a remote call, too: pyzmq checks for signals
while it waits), and the adapter's context managers stop the simulation on the way out (from a
fresh connection if the interrupted one is stuck mid-request). Further signals while that cleanup
runs are logged and ignored: every step of it is bounded by the simulator timeout.

Against SIGKILL nothing can run here; the remote timeout set at connection bounds the hold.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

__all__ = ["Interrupted", "interrupt_on", "raise_if_interrupted"]

log = logging.getLogger(__name__)

# The signal received under ``interrupt_on``, until the block ends. The handler raises at once,
# but an exception raised where the interpreter cannot propagate it (a finalizer, a weakref
# callback, an isinstance check called from an encoder's C code) is handed to
# ``sys.unraisablehook`` and lost; the run loops call ``raise_if_interrupted`` every step so
# that it is raised again there, and the hook under ``interrupt_on`` keeps such an
# ``Interrupted`` off stderr (it is not lost, so there is nothing to report).
_pending: list[int] = []


def raise_if_interrupted() -> None:
    """Raise ``Interrupted`` if a signal arrived under ``interrupt_on`` (for run loops)."""
    if _pending:
        raise Interrupted(_pending[0])


class Interrupted(KeyboardInterrupt):
    """The run was interrupted by a signal (a KeyboardInterrupt: no ``except Exception``
    swallows it).

    Attributes:
        signum: the signal's number.
        simulator_released: set by the lattice's cleanup: True when the simulation it started
            was stopped (stepping released), False when that failed, None when not known.
    """

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.simulator_released: bool | None = None
        super().__init__(self.name)

    @property
    def name(self) -> str:
        """The signal's name, e.g. 'SIGINT'."""
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + its number."""
        return 128 + self.signum


@contextmanager
def interrupt_on(*signums: int) -> Iterator[None]:
    """Within the block, the first of ``signums`` (default SIGINT, SIGTERM) raises Interrupted.

    Only the main thread can install handlers; elsewhere this does nothing.
    """
    signums = signums or (signal.SIGINT, signal.SIGTERM)
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    raised = False

    def handler(signum: int, frame: FrameType | None) -> None:
        nonlocal raised
        if raised:
            log.warning("%s: already stopping (each step is bounded by the timeouts)", signum)
            return
        raised = True
        _pending.append(signum)
        raise Interrupted(signum)

    previous = {signum: signal.signal(signum, handler) for signum in signums}
    unraisable = sys.unraisablehook

    def quiet_about_interrupted(report: Any) -> None:
        if not isinstance(report.exc_value, Interrupted):
            unraisable(report)

    sys.unraisablehook = quiet_about_interrupted
    try:
        yield
    finally:
        _pending.clear()
        sys.unraisablehook = unraisable
        for signum, old in previous.items():
            signal.signal(signum, old)
