"""Keep a step's large temporaries in the heap instead of fresh pages from the kernel.

A live step on a fine footprint builds a few arrays of megabytes (a 512 x 512 box of modes is
2 MiB) and frees them at once. glibc serves blocks above its mmap threshold (128 KiB at start,
raised only by the first frees of such blocks, so whether it ever covers them depends on the
process's history) with a fresh ``mmap`` and returns them with ``munmap``: every temporary is
then faulted in and zeroed page by page. Measured on membrane-live, a ``read`` after a step with
one load at twice ``min_radius`` took 1.2-2.0 ms in some server processes and 5.2-6.4 ms in
others, the slow ones spending it in page faults (``ndarray.copy`` 13 times slower).

Fixing both thresholds keeps blocks up to 32 MiB in the heap and its freed top in place; the
server hands freed memory back to the system on its own schedule (``server.MemoryRelease``,
``malloc_trim``, found here too), so the heap does not stay at its peak.
"""

from __future__ import annotations

import ctypes
import logging
from collections.abc import Callable
from typing import Any

__all__ = [
    "MMAP_THRESHOLD_BYTES",
    "TRIM_THRESHOLD_BYTES",
    "keep_temporaries_in_heap",
    "malloc_trim_function",
]

logger = logging.getLogger(__name__)

# glibc's largest mmap threshold on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX): blocks below it come
# from the heap. Above it (a film's tables, a scene build) mmap is the right thing.
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
# Free memory at the heap's top kept for the next step rather than trimmed at every free.
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
_M_TRIM_THRESHOLD = -1  # mallopt's parameter numbers (malloc.h)
_M_MMAP_THRESHOLD = -3


def keep_temporaries_in_heap() -> bool:
    """Set glibc's mmap and trim thresholds for this process; False where the C library has no
    ``mallopt`` (musl, macOS) or refused them, which costs only speed."""
    mallopt = _libc_function("mallopt")
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    done = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    done = bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)) and done
    if not done:
        logger.debug("mallopt refused the heap thresholds: large temporaries stay on mmap")
    return done


def malloc_trim_function() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` (hands the heap's free pages back), or None where the C library
    has none (musl, macOS)."""
    trim: Callable[[int], int] | None = _libc_function("malloc_trim")
    return trim


def _libc_function(name: str) -> Any:
    """A function of this process's C library, or None where it has none by that name."""
    try:
        return getattr(ctypes.CDLL(None), name)
    except (OSError, AttributeError):
        return None
