"""The wire codec: round trips, arrays, malformed input, reply checking, and the spec's codes."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from membrane_client.errors import ProtocolError, ServerError
from membrane_client.protocol import (
    PROTOCOL_VERSION,
    ErrorCode,
    Op,
    Request,
    RequestError,
    check_reply,
    decode,
    encode,
    error_reply,
    ok_reply,
    pack_array,
    peek_reply,
    unpack_array,
)

PROTOCOL_DOC = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"

# Values msgpack carries unchanged (NaN left out: it never equals itself).
scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=False)
    | st.text(max_size=20)
    | st.binary(max_size=40)
)
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
INPUT_DTYPES: list[np.dtype[Any]] = [np.dtype("<f4"), np.dtype(">f4"), np.dtype("<f8")]
messages = st.dictionaries(st.text(max_size=12), values, max_size=6)


@given(messages)
def test_encode_decode_round_trip(message: dict[str, Any]) -> None:
    assert decode(encode(message)) == message


@given(st.binary(max_size=200))
def test_decode_garbage_gives_a_map_or_protocol_error(data: bytes) -> None:
    try:
        message = decode(data)
    except ProtocolError:
        return
    assert isinstance(message, dict)
    assert all(isinstance(key, str) for key in message)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\xc1",  # a byte msgpack never uses
        msgpack.packb([1, 2, 3]),
        msgpack.packb("query"),
        msgpack.packb({1: "int key"}, strict_types=False),
        msgpack.packb({"v": 1}) + b"\x00",  # trailing bytes
        msgpack.packb({"v": 1})[:-1],  # truncated
        msgpack.packb({"op": "query", "t": 0.5})[:-3],  # truncated inside a float
    ],
)
def test_decode_rejects_what_is_not_one_string_keyed_map(data: bytes) -> None:
    with pytest.raises(ProtocolError):
        decode(data)


@settings(max_examples=60)
@given(
    hnp.arrays(
        dtype=st.sampled_from(INPUT_DTYPES),
        shape=hnp.array_shapes(min_dims=1, max_dims=3, min_side=0, max_side=6),
        elements=st.floats(width=32, allow_nan=False),
    ),
    st.sampled_from(["<f4", "<f8"]),
)
def test_array_round_trip_is_exact(array: np.ndarray, dtype: str) -> None:
    packed = pack_array(array, dtype)
    wire = decode(encode({"a": packed}))["a"]
    unpacked = unpack_array(wire)
    assert unpacked.dtype == np.dtype(dtype)
    assert unpacked.shape == array.shape
    np.testing.assert_array_equal(unpacked, array.astype(dtype))


def test_array_bytes_are_little_endian_float32() -> None:
    packed = pack_array(np.array([1.0, -2.5], dtype=">f8"))
    assert packed["dtype"] == "<f4"
    assert packed["data"] == np.array([1.0, -2.5], dtype="<f4").tobytes()
    assert packed["shape"] == [2]


@pytest.mark.parametrize(
    "obj",
    [
        [1, 2],
        {"dtype": "<i4", "shape": [1], "data": b"\x00" * 4},
        {"dtype": "<f4", "shape": [2], "data": b"\x00" * 4},
        {"dtype": "<f4", "shape": [-1], "data": b""},
        {"dtype": "<f4", "shape": [True], "data": b"\x00" * 4},
        {"dtype": "<f4", "shape": "1", "data": b"\x00" * 4},
        {"dtype": "<f4", "shape": [1], "data": "text"},
        {"shape": [1], "data": b"\x00" * 4},
    ],
)
def test_unpack_array_rejects_malformed_maps(obj: Any) -> None:
    with pytest.raises(ProtocolError):
        unpack_array(obj)


def test_pack_array_refuses_other_dtypes() -> None:
    with pytest.raises(ValueError, match="dtype"):
        pack_array(np.zeros(2), "<i8")


def test_a_request_sends_only_the_fields_it_has_and_reads_back_the_same() -> None:
    query = Request(Op.QUERY, 17, session="abc", t=0.25)
    message = decode(query.to_wire())
    assert message == {"v": PROTOCOL_VERSION, "id": 17, "op": "query", "t": 0.25, "session": "abc"}
    assert Request.from_wire(query.to_wire()) == query
    float64 = Request(Op.QUERY, 18, scene="rope", t=1.0, dtype="<f8")
    assert Request.from_wire(float64.to_wire()) == float64


@pytest.mark.parametrize(
    ("message", "code", "envelope"),
    [
        (b"\x93\x01\x02\x03", ErrorCode.BAD_MESSAGE, False),  # an array, not a map
        ({"v": 1, "id": -1, "op": "ping"}, ErrorCode.BAD_REQUEST, False),
        ({"v": 1.0, "id": 1, "op": "ping"}, ErrorCode.BAD_VERSION, False),
        ({"v": 1, "id": 1, "op": "fly"}, ErrorCode.UNKNOWN_OP, False),
        ({"v": 1, "id": 1, "op": "ping", "session": "x" * 65}, ErrorCode.BAD_REQUEST, False),
        ({"v": 1, "id": 1, "op": "describe", "scene": 3}, ErrorCode.BAD_REQUEST, True),
        ({"v": 1, "id": 1, "op": "query"}, ErrorCode.BAD_REQUEST, True),
        ({"v": 1, "id": 1, "op": "query", "t": "0.5"}, ErrorCode.BAD_REQUEST, True),
        ({"v": 1, "id": 1, "op": "query", "t": True}, ErrorCode.BAD_REQUEST, True),
        ({"v": 1, "id": 1, "op": "query", "t": float("nan")}, ErrorCode.INVALID_TIME, True),
        ({"v": 1, "id": 1, "op": "query", "t": 0.0, "dtype": "<i4"}, ErrorCode.BAD_REQUEST, True),
    ],
)
def test_a_request_that_breaks_the_schema_is_refused_with_its_code(
    message: bytes | dict[str, Any], code: ErrorCode, envelope: bool
) -> None:
    data = message if isinstance(message, bytes) else encode(message)
    with pytest.raises(RequestError) as refused:
        Request.from_wire(data)
    assert refused.value.code == code
    # The envelope (op, id, session) is known exactly when it was valid: the stats count it.
    assert (refused.value.request is not None) == envelope
    if envelope:
        assert refused.value.request_id == 1


def test_peek_reply_reads_the_envelope_alone() -> None:
    frame = {"z": {"dtype": "<f4", "shape": [2], "data": b"\x00" * 8}}
    assert peek_reply(encode(ok_reply(7, **frame))) == (7, None)
    error = encode(error_reply(8, ErrorCode.OUT_OF_DOMAIN, "past the end"))
    assert peek_reply(error) == (8, "out_of_domain")
    assert peek_reply(encode({"ok": True, "v": 1, "id": 9})) == (9, None)  # another order
    assert peek_reply(b"\xc1garbage") == (-1, "undecodable")
    assert peek_reply(encode({"v": 1, "id": 3, "ok": False})) == (3, "error_without_code")


def test_check_reply_returns_ok_replies() -> None:
    reply = decode(encode(ok_reply(5, pong=True)))
    assert check_reply(reply, 5)["pong"] is True


def test_check_reply_raises_server_error_with_code() -> None:
    reply = decode(encode(error_reply(9, ErrorCode.OUT_OF_DOMAIN, "t past\nthe end")))
    with pytest.raises(ServerError) as caught:
        check_reply(reply, 9)
    assert caught.value.code == "out_of_domain"
    assert caught.value.message == "t past the end"  # flattened to one line


def test_check_reply_accepts_error_with_nil_id() -> None:
    with pytest.raises(ServerError) as caught:
        check_reply(error_reply(None, ErrorCode.BAD_MESSAGE, "garbage"), 3)
    assert caught.value.code == ErrorCode.BAD_MESSAGE


@pytest.mark.parametrize(
    "reply",
    [
        {"v": 2, "id": 1, "ok": True},
        {"id": 1, "ok": True},
        {"v": 1, "id": 2, "ok": True},
        {"v": 1, "id": 1},
        {"v": 1, "id": 1, "ok": False},
        {"v": 1, "id": 1, "ok": False, "error": {"code": 3, "message": "x"}},
        {"v": 1, "id": 7, "ok": False, "error": {"code": "bad_request", "message": "x"}},
    ],
)
def test_check_reply_rejects_replies_off_protocol(reply: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError):
        check_reply(reply, 1)


def test_error_codes_match_the_spec() -> None:
    text = PROTOCOL_DOC.read_text()
    section = text.split("## Error codes", 1)[1].split("\n## ", 1)[0]
    documented = set(re.findall(r"^\| `([a-z_]+)` \|", section, flags=re.MULTILINE))
    assert documented == {code.value for code in ErrorCode}


def test_ops_match_the_spec() -> None:
    text = PROTOCOL_DOC.read_text()
    documented = set(re.findall(r"^### `([a-z_]+)`", text, flags=re.MULTILINE))
    assert documented == {op.value for op in Op}


def test_values_from_a_peer_are_previewed_within_bounds() -> None:
    from membrane_client.protocol import preview

    deep: list[object] = []
    for _ in range(5000):
        deep = [deep]
    assert preview(deep) == "an array of 1"
    assert preview({"a": 1}) == "a map of 1"
    assert preview("x" * 10_000).endswith("(10000 long)")
    assert len(preview("x" * 10_000)) < 100
    assert preview(2**64 - 1) == repr(2**64 - 1)
