"""The haptic loop's two processes share one small block of memory: the device side writes the
proxy's position and force each tick, the network side the last step's contact after each reply.

A memory-mapped file (no broker, no pickling, nothing to clean up but the file) holding float64
slots. Each side's record is guarded by a sequence lock: the writer makes its counter odd,
writes, makes it even; a reader copies the record and keeps the copy only if the counter was
even and unchanged across it, so that neither side ever waits on the other (the servo thread
never blocks on the network). One writer per record.
"""

from __future__ import annotations

import ctypes
import mmap
import os
import tempfile
from enum import IntEnum
from pathlib import Path
from typing import Any, NamedTuple, cast

__all__ = ["Channel", "ContactRecord", "State"]

_PROXY, _PROXY_FIELDS = 0, 5  # seq, then x, y (unused on a string), depth, force, k
_CONTACT, _CONTACT_FIELDS = 6, 9  # seq, then ContactRecord's fields in order
_STATE, _STOP, _DT = 16, 17, 18
_SLOTS = 24
_READ_TRIES = 64


class State(IntEnum):
    """The network side's state, as it writes it."""

    STARTING = 0
    RUNNING = 1
    STOPPED = 2
    FAILED = 3


class ContactRecord(NamedTuple):
    """What the network side last received (``Contact`` is built from it)."""

    k: int  # steps taken by the session (the record is of step k - 1)
    free: float  # the next step's free displacement under the tip, without the tip's force
    compliance: float  # the one-step compliance under the tip
    static_compliance: float
    force: float  # the force the step was taken with
    received: float  # time.monotonic() when the reply arrived
    steps: int  # steps taken by this loop
    skipped: int  # steps not taken because the network side fell behind wall time
    lost: int  # steps whose every reply was lost


class Channel:
    """The shared block, created by the device side (``create``) and opened by the network
    side (``open``) from its path."""

    def __init__(self, path: Path, owner: bool) -> None:
        self.path, self._owner = path, owner
        with open(path, "r+b") as handle:
            self._map = mmap.mmap(handle.fileno(), 8 * _SLOTS)
        # ctypes rather than numpy: a scalar access costs tens of ns, not hundreds
        self._slots = (ctypes.c_double * _SLOTS).from_buffer(self._map)

    @classmethod
    def create(cls) -> Channel:
        handle, name = tempfile.mkstemp(prefix="membrane-haptics-", suffix=".bin")
        os.write(handle, bytes(8 * _SLOTS))
        os.close(handle)
        return cls(Path(name), owner=True)

    @classmethod
    def open(cls, path: Path) -> Channel:
        return cls(path, owner=False)

    def write_proxy(self, x: float, y: float, depth: float, force: float, k: int) -> None:
        """The tip's centre (y unused on a string), the proxy's depth, the force it presses
        with and the step count of the contact that force was rendered from. Slot by slot:
        the servo thread writes this every tick, and a list and a slice cost it a microsecond."""
        slots = self._slots
        slots[_PROXY] += 1.0  # odd: a write in progress
        slots[_PROXY + 1] = x
        slots[_PROXY + 2] = y
        slots[_PROXY + 3] = depth
        slots[_PROXY + 4] = force
        slots[_PROXY + 5] = k
        slots[_PROXY] += 1.0

    def read_proxy(self, dims: int) -> tuple[tuple[float, ...], float, float, int] | None:
        """(at, depth, force, k) as last written, or None before the first."""
        values = self._read(_PROXY, _PROXY_FIELDS)
        if values is None:
            return None
        return tuple(values[:dims]), values[2], values[3], int(values[4])

    def write_contact(self, record: ContactRecord) -> None:
        self._write(
            _CONTACT,
            [
                record.k,
                record.free,
                record.compliance,
                record.static_compliance,
                record.force,
                record.received,
                record.steps,
                record.skipped,
                record.lost,
            ],
        )

    @property
    def contact_version(self) -> float:
        """The contact record's sequence counter: it changes with every write (a cheap test
        for a new record, one slot read)."""
        return float(self._slots[_CONTACT])

    def read_contact(self) -> ContactRecord | None:
        """The last record, or None before the first (or while a write is in progress)."""
        values = self._read(_CONTACT, _CONTACT_FIELDS)
        if values is None or values[5] == 0.0:  # ``received`` 0: never written
            return None
        k, free, c, static, force, received, steps, skipped, lost = values
        counts = int(steps), int(skipped), int(lost)
        return ContactRecord(int(k), free, c, static, force, received, *counts)

    @property
    def state(self) -> State:
        return State(int(self._slots[_STATE]))

    @state.setter
    def state(self, value: State) -> None:
        self._slots[_STATE] = float(value)

    @property
    def stop_requested(self) -> bool:
        return bool(self._slots[_STOP])

    def request_stop(self) -> None:
        self._slots[_STOP] = 1.0

    @property
    def dt(self) -> float:
        return float(self._slots[_DT])

    @dt.setter
    def dt(self, value: float) -> None:
        self._slots[_DT] = value

    def close(self) -> None:
        """Unmap (and, on the creating side, remove the file)."""
        del self._slots
        self._map.close()
        if self._owner:
            self.path.unlink(missing_ok=True)

    def _write(self, start: int, values: list[float]) -> None:
        slots = self._slots
        slots[start] += 1.0  # odd: a write in progress
        cast(Any, slots)[start + 1 : start + 1 + len(values)] = values
        slots[start] += 1.0

    def _read(self, start: int, count: int) -> list[float] | None:
        slots = self._slots
        for _ in range(_READ_TRIES):
            before = slots[start]
            if before % 2.0:
                continue
            values = slots[start + 1 : start + 1 + count]
            if slots[start] == before:
                return values if before else None
        return None
