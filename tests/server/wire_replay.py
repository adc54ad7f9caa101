"""Recorded wire traffic: request bytes of every op (and of every kind of refusal), and the reply
bytes the server gave them, so that a change inside the server can be shown not to change the
wire.

    python tests/server/wire_replay.py     # records tests/server/wire_recording.msgpack

``test_wire_replay.py`` replays the recorded requests against a fresh dispatcher and compares
each reply, byte for byte once a few fields are masked: those that differ from run to run by
nature (``MASKED``: wall-clock times, uptime, latency figures and their age, the server's
version) and the process-wide log counters. Re-record only when a change to the wire is meant,
and say so in CHANGELOG.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from membrane_client.protocol import decode, encode
from membrane_server.dispatch import Dispatcher
from membrane_server.served import ServedScene
from membrane_server.sessions import SessionTable
from membrane_server.stats import Stats

RECORDING = Path(__file__).with_name("wire_recording.msgpack")
SCENES = ("rope", "membrane-live", "rope-live")
# Fields whose values differ between runs by nature (at any depth of a reply).
MASKED = frozenset({"time", "uptime_s", "latency_us", "age_s", "server", "log"})


def requests() -> list[bytes]:
    """The recorded requests, in order: every op, with and without its options, and a
    refusal of each kind the dispatcher and the live ops give."""

    def message(id_: int, op: str, **fields: Any) -> bytes:
        return encode({"v": 1, "id": id_, "op": op, **fields})

    shape = np.linspace(0.0, 1e-3, 100, dtype="<f4")
    initial = {"displacement": {"dtype": "<f4", "shape": [100], "data": shape.tobytes()}}
    probe = {"at": [0.5, 0.5], "depth": 1e-3, "radius": 0.05}
    load = {"at": [0.3, 0.6], "force": 0.5, "radius": 0.08}
    live = {"scene": "membrane-live", "session": "m1", "token": "t-m1"}
    rope = {"scene": "rope-live", "session": "r1", "token": "t-r1"}
    out = [
        message(1, "hello", session="s"),
        message(2, "describe", scene="rope"),
        message(3, "describe", scene="membrane-live"),
        message(4, "query", scene="rope", t=0.25),
        message(5, "query", scene="rope", t=0.2512),
        message(6, "query", scene="rope", t=0.5, dtype="<f8"),
        message(7, "query", scene="rope", t=7.0),
        message(8, "query", scene="rope", t=float("nan")),
        message(9, "ping"),
        message(10, "open", **live),
        message(11, "step", **live, k=0, probes=[probe]),
        message(12, "step", **live, k=1, loads=[load], probes=[probe], frame=False),
        message(12, "step", **live, k=1, loads=[load], probes=[probe], frame=False),  # resent
        message(13, "read", **live),
        message(14, "step", **live, k=5),
        message(15, "step", **live, k=2, probes=[{**probe, "radius": 1e-320}]),
        message(16, "step", **live, k=2, loads=[{**load, "force": 1e308}]),
        message(17, "open", **live),
        message(18, "reset", **live),
        message(19, "open", **rope, initial=initial),
        message(20, "step", **rope, k=0, loads=[{"at": [0.4], "force": 1.0, "radius": 0.0}]),
        message(
            30,
            "step",
            **rope,
            k=1,
            grasps=[{"at": [0.3], "height": 1e-3, "radius": 0.0}],
            probes=[{"at": [0.7], "depth": -1e-3, "radius": 0.0}],
            dtype="<f8",
        ),
        message(31, "read", **rope),
        message(
            32,
            "step",
            **rope,
            k=2,
            dtype="<f8",
            tools=[
                {"kind": "sphere", "at": [0.5], "depth": 1e-3, "radius": 0.05},
                {"kind": "cylinder", "at": [0.2], "depth": -1e-3, "radius": 0.03},
            ],
        ),
        message(
            33,
            "step",
            **rope,
            k=3,
            tools=[{"kind": "blade", "at": [0.5], "depth": 0.0, "radius": 0.05}],
        ),
        message(34, "read", **rope),
        message(21, "close", **rope),
        message(22, "close", **rope),
        message(23, "read", **rope),
        message(24, "open", scene="rope", session="f1"),
        message(25, "step", scene="membrane-live", session="m1", k="one"),
        message(26, "nonsense"),
        message(27, "describe", scene="nowhere"),
        encode({"v": 2, "id": 28, "op": "ping"}),
        b"\xc1not msgpack",
        message(29, "stats"),
    ]
    return out


def served() -> Dispatcher:
    stats = Stats()
    scenes = [ServedScene.load(name) for name in SCENES]
    return Dispatcher(scenes, stats.snapshot, SessionTable())


def replies(dispatcher: Dispatcher, sent: list[bytes]) -> list[bytes]:
    return [dispatcher.handle([payload]).reply for payload in sent]


def masked(reply: bytes) -> bytes:
    """The reply re-encoded with the ``MASKED`` fields set to nil, order and types kept."""
    return encode(_mask(decode(reply)))


def _mask(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: None if k in MASKED else _mask(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_mask(v) for v in value]
    return value


def record() -> None:
    sent = requests()
    pairs = list(zip(sent, replies(served(), sent), strict=True))
    RECORDING.write_bytes(msgpack.packb(pairs, use_bin_type=True))
    print(f"recorded {len(pairs)} requests and replies in {RECORDING}")


# Numbers may differ from the recording in their last digits where numpy's vectorised sin, exp
# or BLAS differ between builds (numpy 2.4.6 against the recording's build: at most 2 ulps, in
# frames and probe readings): that is arithmetic, not the wire. Everything else (keys, their
# order, types, strings, shapes) must match exactly. A value within ZERO of zero has no last digits
# of its own: it is what is left of a sum that cancels (the rope at rest at t = 1: 1e-19, varying
# by 7e-20 between CPUs' vector paths), so two such values are equal. ZERO is a ten-millionth of
# the smallest amplitude the recording holds (4.3e-5).
ULPS = 8
ZERO = 1e-12


def differences(after: Any, before: Any, where: str = "") -> list[str]:
    """Where two decoded replies differ beyond ``ULPS`` units in the last place of a number."""
    if isinstance(before, dict) and isinstance(after, dict):
        if list(after) != list(before):
            return [f"{where}: keys {list(after)} != {list(before)}"]
        if "dtype" in before and isinstance(before.get("data"), bytes):
            return _array_differences(after, before, where)
        return [d for k in before for d in differences(after[k], before[k], f"{where}.{k}")]
    if isinstance(before, list) and isinstance(after, list):
        if len(after) != len(before):
            return [f"{where}: {len(after)} items != {len(before)}"]
        return [
            d
            for i, (a, b) in enumerate(zip(after, before, strict=True))
            for d in differences(a, b, f"{where}[{i}]")
        ]
    if type(after) is not type(before):
        return [f"{where}: {type(after).__name__} != {type(before).__name__}"]
    if isinstance(before, float):
        if before == after or (np.isnan(before) and np.isnan(after)):
            return []
        if max(abs(before), abs(after)) < ZERO:
            return []
        gap = abs(after - before) / max(np.spacing(abs(before)), np.spacing(abs(after)))
        return [] if gap <= ULPS else [f"{where}: {after!r} != {before!r}"]
    return [] if after == before else [f"{where}: {str(after)[:80]} != {str(before)[:80]}"]


def _array_differences(after: dict[str, Any], before: dict[str, Any], where: str) -> list[str]:
    head = {k: v for k, v in before.items() if k != "data"}
    if {k: v for k, v in after.items() if k != "data"} != head:
        return [f"{where}: array header {after} != {head}"]
    a = np.frombuffer(after["data"], dtype=after["dtype"])
    b = np.frombuffer(before["data"], dtype=before["dtype"])
    if a.shape != b.shape:
        return [f"{where}: {a.size} values != {b.size}"]
    if not np.issubdtype(b.dtype, np.floating):
        return [] if np.array_equal(a, b) else [f"{where}: values differ"]
    spacing = np.maximum(np.spacing(np.abs(b)), np.spacing(np.abs(a)))
    noise = np.maximum(np.abs(a), np.abs(b)) < ZERO
    gap = float(np.max(np.where(noise, 0.0, np.abs(a - b) / spacing), initial=0.0))
    return [] if gap <= ULPS else [f"{where}: values differ by {gap:.3g} ulps"]


def recorded() -> list[tuple[bytes, bytes]]:
    pairs = msgpack.unpackb(RECORDING.read_bytes(), raw=False)
    return [(bytes(request), bytes(reply)) for request, reply in pairs]


if __name__ == "__main__":
    record()
