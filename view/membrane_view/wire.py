"""The frames the bridge pushes to the page: a 32-byte header and float32 displacements.

Layout (little-endian), read by static/view.js with a DataView and a Float32Array:

====== ======= ============================================================
offset type    field
====== ======= ============================================================
0      4 bytes magic ``MBF1``
4      uint32  k: the frame's step index
8      float64 t: simulation time (s)
16     float32 force: the probe's contact force (0 with no probe; NaN on a film)
20     uint32  n: number of float32 values that follow
24     float32 bridge_us: the bridge's own time on the previous frame (us)
28     uint32  flags: bit 0 live, bit 1 probe in contact
32     n x float32 z, row-major in the lattice's shape
====== ======= ============================================================

Everything else (the scene's description, stats, errors) travels as JSON text messages.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

__all__ = ["FLAG_CONTACT", "FLAG_LIVE", "HEADER", "HEADER_SIZE", "MAGIC", "WireFrame",
           "decode_frame", "encode_frame"]  # fmt: skip

MAGIC = b"MBF1"
HEADER = struct.Struct("<4sIdfIfI")
HEADER_SIZE = HEADER.size  # 32: the float32 array starts 4-byte aligned
FLAG_LIVE = 1
FLAG_CONTACT = 2


class WireFrame(NamedTuple):
    k: int
    t: float
    force: float
    bridge_us: float
    flags: int
    z: np.ndarray  # float32, flat


def encode_frame(
    k: int, t: float, z: np.ndarray, *, force: float = float("nan"), bridge_us: float = 0.0,
    flags: int = 0,
) -> bytes:  # fmt: skip
    """One binary WebSocket message: the header and ``z`` as little-endian float32."""
    values = np.ascontiguousarray(z, dtype="<f4").reshape(-1)
    header = HEADER.pack(MAGIC, k, t, force, values.size, bridge_us, flags)
    return header + values.tobytes()


def decode_frame(data: bytes) -> WireFrame:
    """The inverse of ``encode_frame`` (tests, tools); ValueError on a malformed message."""
    if len(data) < HEADER_SIZE:
        raise ValueError(f"a frame is at least {HEADER_SIZE} bytes, got {len(data)}")
    magic, k, t, force, n, bridge_us, flags = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ValueError(f"bad magic {magic!r}")
    if len(data) != HEADER_SIZE + 4 * n:
        raise ValueError(f"header says {n} values, message holds {len(data) - HEADER_SIZE} bytes")
    z = np.frombuffer(data, dtype="<f4", offset=HEADER_SIZE, count=n)
    return WireFrame(k, t, force, bridge_us, flags, z)
