"""The wire as recorded: every op's replies, byte for byte (a few run-dependent fields masked).

The recording (``wire_recording.msgpack``, made by ``python tests/server/wire_replay.py``) holds
request bytes of every op and of each kind of refusal, and the replies the server gave them.
Refactoring inside the server, the models or the client's schema must leave them unchanged.
"""

from __future__ import annotations

import numpy as np
from wire_replay import differences, masked, recorded, replies, requests, served

from membrane_client.protocol import decode, encode


def test_the_recording_is_of_todays_requests() -> None:
    assert [request for request, _ in recorded()] == requests()


def test_every_reply_is_the_recorded_one() -> None:
    pairs = recorded()
    now = replies(served(), [request for request, _ in pairs])
    for index, ((_, before), after) in enumerate(zip(pairs, now, strict=True)):
        found = differences(decode(masked(after)), decode(masked(before)))
        assert not found, (index, found)


def test_the_masking_would_catch_a_changed_reply() -> None:
    """Its power: a reply differing anywhere but in a masked field is told apart."""
    _, reply = recorded()[3]  # a query
    message = decode(reply)
    message["t"] = message["t"] + 1e-12
    assert masked(encode(message)) != masked(reply)
    _, stats = recorded()[-1]
    message = decode(stats)
    message["uptime_s"], message["latency_us"] = 1e9, {"p50": 1.0}  # masked: no difference
    assert masked(encode(message)) == masked(stats)
    message["requests"] += 1
    assert masked(encode(message)) != masked(stats)


def test_the_comparison_tells_arithmetic_from_a_changed_reply() -> None:
    """Its power: last-digit noise (and noise at rest) passes; a changed number, key order or
    frame does not."""
    _, reply = recorded()[5]  # a query with a frame
    message = decode(reply)
    assert differences(message, decode(reply)) == []
    frame = np.frombuffer(message["z"]["data"], dtype=message["z"]["dtype"]).copy()
    nudged = dict(message, z=dict(message["z"], data=np.nextafter(frame, np.inf).tobytes()))
    assert differences(nudged, message) == []
    frame[3] *= 1.0 + 1e-9
    changed = dict(message, z=dict(message["z"], data=frame.tobytes()))
    assert differences(changed, message)
    assert differences(dict(message, t=message["t"] * (1 + 1e-12)), message)
    at_rest = dict(message, z=dict(message["z"], data=np.full_like(frame, 1e-19).tobytes()))
    noise = dict(message, z=dict(message["z"], data=np.full_like(frame, 7e-20).tobytes()))
    moved = dict(message, z=dict(message["z"], data=np.full_like(frame, 1e-9).tobytes()))
    assert differences(noise, at_rest) == [] and differences(moved, at_rest)
    assert differences(dict(reversed(list(message.items()))), message)
