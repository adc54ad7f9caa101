"""The wire codec, version 1: one msgpack map per message (spec: docs/PROTOCOL.md).

Both sides use this module: the client to build requests and read replies, the server to read
requests and build replies. It depends on msgpack and numpy only.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import msgpack
import numpy as np

from membrane_client.errors import ProtocolError, ServerError, UserError

__all__ = [
    "ARRAY_DTYPES",
    "MAX_LATTICE_POINTS",
    "MAX_NESTING",
    "MAX_REPLY_BYTES",
    "MAX_REQUEST_BYTES",
    "MAX_SESSION_CHARS",
    "PROTOCOL_VERSION",
    "Domain",
    "EncodedFields",
    "ErrorCode",
    "Op",
    "check_reply",
    "decode",
    "encode",
    "encode_fields",
    "encode_ok_reply",
    "error_reply",
    "ok_reply",
    "pack_array",
    "preview",
    "request",
    "unpack_array",
]

PROTOCOL_VERSION = 1

# Limits (docs/PROTOCOL.md, "Limits"). Requests are tiny maps; replies carry whole frames.
MAX_REQUEST_BYTES = 64 * 1024
MAX_REPLY_BYTES = 64 * 1024 * 1024
MAX_LATTICE_POINTS = 65_536
MAX_SESSION_CHARS = 64
# No message of the protocol nests deeper than 4 levels (a reply's describe fields); a bound well
# above that keeps every walk over a decoded message, and every repr of one, shallow.
MAX_NESTING = 32
# How much of a client's value an error message or a log line shows.
_PREVIEW_CHARS = 64

# Little-endian float32 for displacements, float64 for coordinates (never lose digits of a time
# or a position on the wire).
ARRAY_DTYPES = ("<f4", "<f8")


class Op(StrEnum):
    """The operations a version-1 server answers."""

    HELLO = "hello"
    DESCRIBE = "describe"
    QUERY = "query"
    STATS = "stats"
    PING = "ping"


class ErrorCode(StrEnum):
    """The ``code`` of an error reply."""

    BAD_MESSAGE = "bad_message"
    BAD_VERSION = "bad_version"
    BAD_REQUEST = "bad_request"
    UNKNOWN_OP = "unknown_op"
    UNKNOWN_SCENE = "unknown_scene"
    INVALID_TIME = "invalid_time"
    OUT_OF_DOMAIN = "out_of_domain"
    INTERNAL_ERROR = "internal_error"


class Domain(StrEnum):
    """Where a query's time fell, as the ``domain`` field of a query reply says."""

    INSIDE = "inside"
    CLAMPED = "clamped"
    HELD = "held"


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
        text = repr(value[:_PREVIEW_CHARS])
        return text if len(value) <= _PREVIEW_CHARS else f"{text}... ({len(value)} long)"
    text = repr(value)
    return text if len(text) <= _PREVIEW_CHARS else text[:_PREVIEW_CHARS] + "..."


def _nesting_exceeds(message: dict[str, Any], limit: int) -> bool:
    """True when containers nest more than ``limit`` levels (iterative: no recursion)."""
    pending: list[tuple[Any, int]] = [(message, 1)]
    while pending:
        container, depth = pending.pop()
        if depth > limit:
            return True
        values = container.values() if isinstance(container, dict) else container
        pending.extend((v, depth + 1) for v in values if isinstance(v, dict | list))
    return False


def request(op: str, request_id: int, **fields: Any) -> dict[str, Any]:
    """Build a request envelope; fields whose value is None are left out."""
    message: dict[str, Any] = {"v": PROTOCOL_VERSION, "id": int(request_id), "op": str(op)}
    message.update({key: value for key, value in fields.items() if value is not None})
    return message


def ok_reply(request_id: int | None, **fields: Any) -> dict[str, Any]:
    """Build a success reply to the request with this id."""
    return {"v": PROTOCOL_VERSION, "id": request_id, "ok": True, **fields}


@dataclass(frozen=True)
class EncodedFields:
    """A reply's fields serialised once, to be sent to many requests (``encode_ok_reply``)."""

    count: int
    data: bytes

    def plus(self, key: str, value: Any) -> EncodedFields:
        """These fields and one more, after them (what ``encode_fields`` would give for the
        fields with ``key`` added last), without encoding the others again."""
        packer = msgpack.Packer(use_bin_type=True)
        return EncodedFields(self.count + 1, self.data + packer.pack(key) + packer.pack(value))


def encode_fields(fields: Mapping[str, Any]) -> EncodedFields:
    """Serialise a success reply's fields (everything but the envelope) once."""
    packer = msgpack.Packer(use_bin_type=True)
    data = b"".join(packer.pack(key) + packer.pack(value) for key, value in fields.items())
    return EncodedFields(len(fields), data)


def encode_ok_reply(request_id: int | None, fields: EncodedFields, **extra: Any) -> bytes:
    """The bytes of ``encode(ok_reply(request_id, **fields, **extra))``, without serialising
    ``fields`` again (a large ``describe`` is encoded once per scene, a frame once per step)."""
    parts = [
        _map_header(len(_ENVELOPE_KEYS) + fields.count + len(extra)),
        _VERSION_FIELD,
        _ID_KEY,
        _pack_scalar(request_id),
        _OK_FIELD,
        fields.data,
    ]
    for key, value in extra.items():
        parts += (msgpack.packb(key), _pack_scalar(value))
    return b"".join(parts)


_ENVELOPE_KEYS = ("v", "id", "ok")
_VERSION_FIELD: bytes = msgpack.packb("v") + msgpack.packb(PROTOCOL_VERSION)
_ID_KEY: bytes = msgpack.packb("id")
_OK_FIELD: bytes = msgpack.packb("ok") + msgpack.packb(True)


def _pack_scalar(value: Any) -> bytes:
    """msgpack bytes of an id or a time, without building a Packer per call (the hot path)."""
    kind = type(value)
    if kind is float:
        return b"\xcb" + _FLOAT64.pack(value)
    if kind is int and 0 <= value < 2**64:
        if value < 128:
            return _FIXINTS[value]
        for marker, limit, width in _UINT_FORMATS:
            if value < limit:
                return marker + value.to_bytes(width, "big")
    if value is None:
        return b"\xc0"
    packed: bytes = msgpack.packb(value, use_bin_type=True)
    return packed


_FLOAT64 = struct.Struct(">d")
_FIXINTS = [bytes([n]) for n in range(128)]
_UINT_FORMATS = ((b"\xcc", 2**8, 1), (b"\xcd", 2**16, 2), (b"\xce", 2**32, 4), (b"\xcf", 2**64, 8))


def _map_header(count: int) -> bytes:
    """msgpack's map header for ``count`` entries (fixmap, map 16 or map 32)."""
    if count < 16:
        return bytes([0x80 | count])
    if count < 2**16:
        return b"\xde" + count.to_bytes(2, "big")
    return b"\xdf" + count.to_bytes(4, "big")


def error_reply(request_id: int | None, code: ErrorCode | str, message: str) -> dict[str, Any]:
    """Build an error reply; ``message`` is flattened to one line."""
    text = " ".join(str(message).split()) or str(code)
    return {
        "v": PROTOCOL_VERSION,
        "id": request_id,
        "ok": False,
        "error": {"code": str(code), "message": text},
    }


def pack_array(array: np.ndarray, dtype: str = "<f4") -> dict[str, Any]:
    """Encode an array as ``{"dtype", "shape", "data"}`` (C order, little-endian)."""
    if dtype not in ARRAY_DTYPES:
        raise UserError(f"dtype must be one of {ARRAY_DTYPES}, got {dtype!r}")
    values = np.ascontiguousarray(array, dtype=np.dtype(dtype))
    return {"dtype": dtype, "shape": [int(n) for n in values.shape], "data": values.tobytes()}


def unpack_array(obj: Any) -> np.ndarray:
    """Decode an array map; raises ProtocolError if it is malformed.

    The result is a read-only view of the message's bytes (no copy).
    """
    if not isinstance(obj, dict):
        raise ProtocolError(f"an array must be a map, got {type(obj).__name__}")
    dtype, shape, data = obj.get("dtype"), obj.get("shape"), obj.get("data")
    if dtype not in ARRAY_DTYPES:
        raise ProtocolError(f"array dtype must be one of {ARRAY_DTYPES}, got {dtype!r}")
    if not isinstance(shape, list) or not all(_is_count(n) for n in shape):
        raise ProtocolError(f"array shape must be a list of non-negative ints, got {shape!r}")
    if not isinstance(data, bytes):
        raise ProtocolError(f"array data must be bin, got {type(data).__name__}")
    itemsize = np.dtype(dtype).itemsize
    expected = math.prod(shape) * itemsize
    if len(data) != expected:
        raise ProtocolError(f"array data is {len(data)} bytes; shape {shape} needs {expected}")
    return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape)


def check_reply(message: Mapping[str, Any], request_id: int) -> dict[str, Any]:
    """Validate a reply to the request ``request_id`` and return it.

    Raises:
        ServerError: The reply is a well-formed error reply (carries its ``code``).
        ProtocolError: The reply does not follow the protocol or answers another request.
    """
    if message.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(f"reply version {message.get('v')!r}, expected {PROTOCOL_VERSION}")
    ok = message.get("ok")
    if not isinstance(ok, bool):
        raise ProtocolError("reply has no boolean 'ok'")
    if not ok:
        error = message.get("error")
        if not isinstance(error, dict):
            raise ProtocolError("error reply without an 'error' map")
        code, text = error.get("code"), error.get("message")
        if not isinstance(code, str) or not isinstance(text, str):
            raise ProtocolError("error reply needs str 'code' and 'message'")
        # An error to a request the server could not read carries id nil: still ours.
        if message.get("id") not in (request_id, None):
            raise ProtocolError(f"reply id {message.get('id')!r} answers another request")
        raise ServerError(code, text)
    if message.get("id") != request_id:
        raise ProtocolError(f"reply id {message.get('id')!r}, expected {request_id}")
    return dict(message)


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
