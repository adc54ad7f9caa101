"""The footprints of recent steps' inputs, kept per basis: the same loads and probes again get
the same (immutable) footprints, neither built nor priced a second time.

A probe held still, a load held, a display's `repeat` and a haptic loop between moves all ask
for the same footprints step after step; one engine serves many sessions, each with inputs of
its own, so the most recent inputs of many steps are kept (least recently used first out),
bounded in entries and in the bytes of their spectra.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from typing import Generic, TypeVar

__all__ = ["FootprintMemo"]

V = TypeVar("V")

MAX_ENTRIES = 256
MAX_BYTES = 8 * 1024 * 1024


class FootprintMemo(Generic[V]):
    """Least recently used values by key, at most ``max_entries`` and ``max_bytes`` in all."""

    def __init__(self, max_entries: int = MAX_ENTRIES, max_bytes: int = MAX_BYTES) -> None:
        self._items: OrderedDict[Hashable, tuple[V, int]] = OrderedDict()
        self._bytes = 0
        self._max_entries, self._max_bytes = max_entries, max_bytes
        self._lock = threading.Lock()  # engines may step in several threads

    def get(self, key: Hashable) -> V | None:
        with self._lock:
            found = self._items.get(key)
            if found is None:
                return None
            self._items.move_to_end(key)
            return found[0]

    def put(self, key: Hashable, value: V, nbytes: int) -> None:
        if nbytes > self._max_bytes // 4:
            return  # one huge entry would push out every other
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old[1]
            self._items[key] = (value, nbytes)
            self._bytes += nbytes
            while len(self._items) > self._max_entries or self._bytes > self._max_bytes:
                _, (_, freed) = self._items.popitem(last=False)
                self._bytes -= freed

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def __len__(self) -> int:
        return len(self._items)
