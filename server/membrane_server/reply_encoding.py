"""Reply bytes built from parts encoded once: the server's hot path.

A ``describe`` of a 65,536-point lattice is a megabyte of coordinates and a frame is encoded once
per step, so the server keeps their fields encoded (``EncodedFields``) and writes each reply's
envelope around them (``encode_ok_reply``). The bytes are exactly those of
``protocol.encode(protocol.ok_reply(...))``, the schema's own encoding (a test checks it).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import msgpack

from membrane_client.protocol import PROTOCOL_VERSION

__all__ = ["EncodedFields", "encode_fields", "encode_ok_reply"]


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
