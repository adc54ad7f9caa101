"""The hello and stats replies, typed: fields in the order the server writes them, read back,
and a malformed reply told as one."""

from __future__ import annotations

from typing import Any

import pytest

from membrane_cli.client_commands import stats_summary
from membrane_client.errors import ProtocolError
from membrane_client.replies import HelloReply, ServerLimits, StatsReply

LIMITS = ServerLimits(131072, 65536, 64, 16, 300.0)
HELLO = HelloReply(1, "membrane 0.2.0", ("hello", "ping"), ("rope",), "rope", "s", LIMITS)


def test_hello_both_ways_in_the_servers_order() -> None:
    fields = HELLO.to_reply_fields()
    assert list(fields) == [
        "protocol", "server", "ops", "scenes", "default_scene", "session", "limits"
    ]  # fmt: skip
    assert list(fields["limits"]) == [
        "max_request_bytes", "max_lattice_points", "max_sessions", "max_sessions_per_peer",
        "session_idle_s",
    ]  # fmt: skip
    assert fields["ops"] == ["hello", "ping"] and fields["scenes"] == ["rope"]
    assert HelloReply.from_reply({"v": 1, "id": 1, "ok": True, **fields}) == HELLO
    older = {k: v for k, v in fields.items() if k not in ("limits", "session", "default_scene")}
    assert HelloReply.from_reply(older) == HelloReply(1, "membrane 0.2.0", HELLO.ops, ("rope",))


@pytest.mark.parametrize(
    "change",
    [{"protocol": "1"}, {"protocol": True}, {"ops": "hello"}, {"scenes": [1]},
     {"default_scene": 3}, {"limits": {"max_sessions": 1}}, {"limits": [1]}],
)  # fmt: skip
def test_a_malformed_hello_is_a_protocol_error(change: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError, match="malformed hello reply"):
        HelloReply.from_reply({**HELLO.to_reply_fields(), **change})


SNAPSHOT: dict[str, Any] = {
    "uptime_s": 3725.0, "requests": 5, "errors": {"bad_request": 1}, "ops": {"query": 4},
    "scenes": {"rope": 4}, "sessions": 2, "latency_us": {"count": 0, "window": 100000},
    "dropped_replies": {}, "failures": 0, "log": {"written": 3}, "peers": 1,
}  # fmt: skip
LIVE = {"open": 1, "steps": 3}


def test_stats_keep_the_snapshots_order_its_open_ended_figures_and_live_last() -> None:
    stats = StatsReply.from_snapshot(SNAPSHOT, LIVE)
    assert stats.extra == {"log": {"written": 3}, "peers": 1} and stats.requests == 5
    fields = stats.to_reply_fields()
    assert list(fields) == [*SNAPSHOT, "live"] and fields == {**SNAPSHOT, "live": LIVE}
    assert StatsReply.from_reply({"v": 1, "id": 7, "ok": True, **fields}) == stats
    # a dispatcher without counters: the live figures alone
    assert StatsReply.from_snapshot({}, LIVE).to_reply_fields() == {"live": LIVE}
    assert StatsReply.from_reply({**SNAPSHOT, "uptime_s": None}).uptime_s is None  # not kept


@pytest.mark.parametrize(
    "change", [{"requests": "5"}, {"requests": True}, {"ops": [1]}, {"uptime_s": "1"}, {"live": 1}]
)
def test_a_malformed_stats_figure_is_a_protocol_error(change: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError, match="malformed stats reply"):
        StatsReply.from_reply({**SNAPSHOT, "live": LIVE, **change})


def test_the_summary_reads_the_typed_reply_as_the_map() -> None:
    typed = StatsReply.from_snapshot(SNAPSHOT, LIVE)
    summary = stats_summary(typed)
    assert summary == stats_summary({"v": 1, "id": 7, "ok": True, **typed.to_reply_fields()})
    lines = summary.splitlines()
    assert lines[0] == "up 1 h 02 min, 5 requests, 2 sessions"
    assert "peers: 1" in lines and "live: steps 3, open 1" in lines and "log: written 3" in lines
