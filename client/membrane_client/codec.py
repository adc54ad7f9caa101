"""The bounded msgpack codec under every message: maps in and out, arrays, and the short text a
peer's value is quoted as.

``protocol`` (the envelope, requests, replies) and ``live_schema`` (the live session's items and
replies) both build on it; it depends on msgpack and numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgpack
import numpy as np

from membrane_client.errors import ProtocolError, UserError

__all__ = [
    "ARRAY_DTYPES",
    "MAX_ARRAY_DIMS",
    "MAX_NESTING",
    "MAX_REPLY_BYTES",
    "PREVIEW_CHARS",
    "decode",
    "encode",
    "pack_array",
    "preview",
    "unpack_array",
]

MAX_REPLY_BYTES = 64 * 1024 * 1024
# No array of the protocol has more than 2 axes (a lattice's frame); numpy stops at 64.
MAX_ARRAY_DIMS = 8
# No message of the protocol nests deeper than 4 levels (a reply's describe fields); a bound well
# above that keeps every walk over a decoded message, and every repr of one, shallow.
MAX_NESTING = 32
# How much of a client's value an error message or a log line shows.
PREVIEW_CHARS = 64

# Little-endian float32 for displacements, float64 for coordinates (never lose digits of a time
# or a position on the wire).
ARRAY_DTYPES = ("<f4", "<f8")


def encode(message: Mapping[str, Any]) -> bytes:
    """Serialise one message (a map with str keys) to msgpack bytes."""
    data: bytes = msgpack.packb(dict(message), use_bin_type=True)
    return data


def decode(data: bytes, max_bytes: int = MAX_REPLY_BYTES) -> dict[str, Any]:
    """Parse one message; raises ProtocolError unless it is a msgpack map with str keys, at most
    ``max_bytes`` long and nested at most ``MAX_NESTING`` levels deep."""
    if len(data) > max_bytes:
        raise ProtocolError(f"a message of {len(data)} bytes, more than the limit {max_bytes}")
    try:
        # unpackb bounds every string, array and map inside by the message's own length.
        message = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises a zoo of types on garbage; all mean the same here
        reason = preview(str(exc))
        raise ProtocolError(f"not a msgpack message: {type(exc).__name__}: {reason}") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"a message must be a msgpack map, got {type(message).__name__}")
    nested = False
    for key, value in message.items():  # one pass: requests are flat, so this is the hot path
        if type(key) is not str:
            raise ProtocolError("a message's keys must all be strings")
        nested = nested or type(value) is dict or type(value) is list
    if nested and _nesting_exceeds(message, MAX_NESTING):
        raise ProtocolError(f"a message may nest at most {MAX_NESTING} levels deep")
    return message


def preview(value: Any) -> str:
    """A short, bounded text for a value a peer sent: for error messages and log lines.

    Containers are named, never formatted (a deep or large one would cost unbounded time and
    memory, or a RecursionError); scalars are shown up to a fixed number of characters.
    """
    if isinstance(value, dict | list | tuple):
        return f"{'a map' if isinstance(value, dict) else 'an array'} of {len(value)}"
    if isinstance(value, str | bytes):
        text = repr(value[:PREVIEW_CHARS])
        return text if len(value) <= PREVIEW_CHARS else f"{text}... ({len(value)} long)"
    text = repr(value)
    return text if len(text) <= PREVIEW_CHARS else text[:PREVIEW_CHARS] + "..."


def _nesting_exceeds(message: dict[str, Any], limit: int) -> bool:
    """True when containers nest more than ``limit`` levels (level by level: no recursion)."""
    level: list[Any] = [message]
    for _ in range(limit):
        inner = []
        for container in level:
            for value in container.values() if type(container) is dict else container:
                if type(value) is dict or type(value) is list:
                    inner.append(value)
        if not inner:
            return False
        level = inner
    return True


def pack_array(array: np.ndarray, dtype: str = "<f4") -> dict[str, Any]:
    """Encode an array as ``{"dtype", "shape", "data"}`` (C order, little-endian)."""
    if dtype not in ARRAY_DTYPES:
        raise UserError(f"dtype must be one of {ARRAY_DTYPES}, got {dtype!r}")
    values = np.ascontiguousarray(array, dtype=np.dtype(dtype))
    return {"dtype": dtype, "shape": [int(n) for n in values.shape], "data": values.tobytes()}


def unpack_array(obj: Any, max_dims: int = MAX_ARRAY_DIMS) -> np.ndarray:
    """Decode an array map; raises ProtocolError if it is malformed.

    The result is a read-only view of the message's bytes (no copy). Nothing of the client's
    value is formatted whole: a dtype is quoted through ``preview``, a shape by its length.
    """
    if not isinstance(obj, dict):
        raise ProtocolError(f"an array must be a map, got {type(obj).__name__}")
    dtype, shape, data = obj.get("dtype"), obj.get("shape"), obj.get("data")
    if dtype not in ARRAY_DTYPES:
        raise ProtocolError(f"array dtype must be one of {ARRAY_DTYPES}, got {preview(dtype)}")
    if not isinstance(shape, list) or not all(_is_count(n) for n in shape):
        reason = f"array shape must be a list of non-negative ints, got {preview(shape)}"
        raise ProtocolError(reason)
    if len(shape) > max_dims:
        raise ProtocolError(f"an array has at most {max_dims} axes, got {len(shape)}")
    if not isinstance(data, bytes):
        raise ProtocolError(f"array data must be bin, got {type(data).__name__}")
    itemsize = np.dtype(dtype).itemsize
    count = len(data) // itemsize
    elements = 0 if 0 in shape else 1
    for n in shape:  # stops once the product passes the data: never a huge integer
        elements *= n
        if elements > count:
            break
    if elements * itemsize != len(data):
        raise ProtocolError(
            f"array data is {len(data)} bytes, which does not fit its shape ({len(shape)} axes)"
        )
    try:  # an empty array may still name axes past numpy's bounds (e.g. [0, 2**62])
        return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape)
    except (ValueError, OverflowError):
        reason = f"an array's shape ({len(shape)} axes) is beyond numpy's bounds"
        raise ProtocolError(reason) from None


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
