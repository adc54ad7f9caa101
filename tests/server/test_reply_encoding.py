"""The server's fast reply path (``reply_encoding``: the envelope written around fields encoded
once) gives, byte for byte, what the wire codec (``membrane_client.protocol.encode``) gives."""

from __future__ import annotations

import numpy as np

from membrane_client.protocol import encode, ok_reply, pack_array
from membrane_server.reply_encoding import encode_fields, encode_ok_reply


def test_a_reply_with_fields_encoded_once_is_byte_for_byte_the_plain_one() -> None:
    fields = {"scene": "s", "points": pack_array(np.arange(6.0).reshape(3, 2), "<f8"), "n": 3}
    for request_id in (0, 1, 127, 128, 2**32, 2**63 - 1, None):
        encoded = encode_ok_reply(request_id, encode_fields(fields))
        assert encoded == encode(ok_reply(request_id, **fields))
        extra = encode_ok_reply(request_id, encode_fields(fields), requested_t=0.1)
        assert extra == encode(ok_reply(request_id, **fields, requested_t=0.1))
    with_revision = encode_fields(fields).plus("revision", "2df4ef8fb9d9")
    assert with_revision == encode_fields({**fields, "revision": "2df4ef8fb9d9"})
    many = {f"k{n}": n for n in range(20)}  # past a fixmap's 15 entries
    assert encode_ok_reply(5, encode_fields(many)) == encode(ok_reply(5, **many))
