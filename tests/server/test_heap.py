"""The server keeps a step's large temporaries in the heap (``heap.keep_temporaries_in_heap``):
without it, glibc served each 2 MiB array of a fine footprint's frame with a fresh mmap, and a
``read`` took 3 to 5 times longer in some server processes than in others."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

_MMAPPED_BLOCKS = """
import ctypes, json, sys
import numpy as np
from membrane_server.heap import keep_temporaries_in_heap

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]

libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MallInfo2
kept = keep_temporaries_in_heap() if sys.argv[1] == "kept" else None
before = libc.mallinfo2().hblks
held = [np.ones(512 * 512) for _ in range(4)]  # four 2 MiB blocks, alive together
print(json.dumps({"kept": kept, "mmapped": libc.mallinfo2().hblks - before}))
"""


def _mmapped_blocks(mode: str) -> dict[str, object]:
    done = subprocess.run(
        [sys.executable, "-c", _MMAPPED_BLOCKS, mode], capture_output=True, text=True, timeout=60
    )
    if done.returncode != 0 and "mallinfo2" in done.stderr:
        pytest.skip("this C library has no mallinfo2 (not glibc 2.33 or later)")
    assert done.returncode == 0, done.stderr
    result: dict[str, object] = json.loads(done.stdout)
    return result


def test_large_temporaries_come_from_the_heap_once_kept() -> None:
    default = _mmapped_blocks("default")
    kept = _mmapped_blocks("kept")
    assert kept["kept"] is True
    # glibc's default in a fresh process: each block on fresh pages of its own
    assert isinstance(default["mmapped"], int) and default["mmapped"] >= 1
    assert kept["mmapped"] == 0
