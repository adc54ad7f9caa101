"""Encoded replies kept per step: a simulator asks for the same steps again and again.

A query that lands on a step (nearest snapping, or linear snapping exactly on a step) always gets
the same fields: only the envelope's ``id`` and the ``requested_t`` differ. Encoding those fields
once per step, and splicing the envelope in front, takes the frame computation, the array
packing and the msgpack encoding of a whole frame off the per-query path.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

from membrane_server.reply_encoding import EncodedFields

__all__ = ["DEFAULT_REPLY_CACHE_BYTES", "ReplyCache"]

# Per scene. A 20 x 20 scene's 101 steps take 180 KB; a 65,536-point scene's frames (256 KiB in
# float32) fit 128 at a time, the oldest making room for the newest.
DEFAULT_REPLY_CACHE_BYTES = 32 * 1024 * 1024


class ReplyCache:
    """Encoded fields by key, within a byte budget (first in, first out past it).

    Args:
        max_bytes: Budget for the encoded bytes held.
    """

    def __init__(self, max_bytes: int = DEFAULT_REPLY_CACHE_BYTES) -> None:
        self.max_bytes = max_bytes
        self.bytes = 0
        self._entries: dict[Hashable, EncodedFields] = {}

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key: Hashable, encode: Callable[[], EncodedFields]) -> EncodedFields:
        """The entry for ``key``, encoded by ``encode()`` and kept on first use."""
        entry = self._entries.get(key)
        if entry is not None:
            return entry
        entry = encode()
        size = len(entry.data)
        if size > self.max_bytes:
            return entry  # larger than the whole budget: never kept
        while self.bytes + size > self.max_bytes:
            oldest = next(iter(self._entries))
            self.bytes -= len(self._entries.pop(oldest).data)
        self._entries[key] = entry
        self.bytes += size
        return entry
