"""The live schema: loads, probes, tools and readings in their wire form, both directions; every
check of a map's form (keys, number types, at's length, finiteness) with short bounded messages;
the open, step/read, reset and close replies, their fields in the order the server writes them."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from membrane_client import live_schema, protocol
from membrane_client.errors import ProtocolError, UserError
from membrane_client.live_limits import (
    DEFAULT_MAX_DEPTH,
    DEFAULT_MAX_FORCE,
    DEFAULT_MAX_RADIUS,
    InvalidInput,
    LiveLimits,
)
from membrane_client.live_schema import (
    LOAD_KEYS,
    MAX_LOADS,
    MAX_PROBES,
    MAX_TOOLS,
    PROBE_KEYS,
    TOOL_KEYS,
    TOOL_KINDS,
    CloseReply,
    Initial,
    LiveInputError,
    LiveStepReply,
    Load,
    OpenReply,
    Probe,
    ProbeReading,
    ResetReply,
    Tool,
    ToolReading,
    loads_from_wire,
    probes_from_wire,
    tools_from_wire,
)
from membrane_client.protocol import Op, Request, RequestError, decode, encode, pack_array

GOOD_LOAD = {"at": [0.5, 0.5], "force": 1.0, "radius": 0.05}
GOOD_PROBE = {"at": [0.5, 0.5], "depth": 1e-5, "radius": 0.05}

# Maps whose form is wrong: (map, what the message says). The first of each kind were the
# engine's own checks of a map; the engine now takes its own types only.
BAD_LOADS: list[tuple[Any, str]] = [
    ({**GOOD_LOAD, "force": math.nan}, "load force must be finite, got nan"),
    ({**GOOD_LOAD, "force": math.inf}, "finite"),
    ({**GOOD_LOAD, "force": -math.inf}, "finite"),
    ({**GOOD_LOAD, "at": [0.5, math.nan]}, "load at must be finite"),
    ({**GOOD_LOAD, "at": [0.5]}, "load at must be 2 numbers, got 1 value"),
    ({**GOOD_LOAD, "at": [0.5, 0.5, 0.5]}, "got 3 values"),
    ({**GOOD_LOAD, "at": 0.5}, "load at must be 2 numbers, got 0.5"),
    ({**GOOD_LOAD, "at": "0.5,0.5"}, "got '0.5,0.5'"),
    ({**GOOD_LOAD, "force": "1"}, "load force must be a number, got a string '1'"),
    ({**GOOD_LOAD, "force": True}, "load force must be a number, got a bool (True)"),
    ({**GOOD_LOAD, "force": None}, "got null"),
    ({**GOOD_LOAD, "force": [1.0]}, "got an array of 1"),
    ({**GOOD_LOAD, "radius": b"x"}, "load radius must be a number, got bytes"),
    ({**GOOD_LOAD, "at": [0.5, 10**400]}, "load at must be a finite number, got a huge integer"),
    ({"at": [0.5, 0.5], "force": 1.0}, "keys ['at', 'force', 'radius'] (missing ['radius'], 0"),
    ({**GOOD_LOAD, "extra": 1}, "needs exactly the keys ['at', 'force', 'radius'] (missing [], 1"),
    ({}, "missing ['at', 'force', 'radius']"),
    ([0.5, 0.5, 1.0], "load must be a map with keys ['at', 'force', 'radius'], got an array of"),
    ("load", "a map with keys"),
]
BAD_PROBES: list[tuple[Any, str]] = [
    ({**GOOD_PROBE, "depth": math.nan}, "probe depth must be finite"),
    ({**GOOD_PROBE, "depth": math.inf}, "finite"),
    ({**GOOD_PROBE, "at": [math.inf, 0.5]}, "probe at must be finite, got inf"),
    ({**GOOD_PROBE, "depth": True}, "probe depth must be a number, got a bool (True)"),
    ({**GOOD_PROBE, "radius": "0.05"}, "probe radius must be a number, got a string '0.05'"),
    ({"at": [0.5, 0.5], "depth": 1e-5}, "needs exactly the keys ['at', 'depth', 'radius']"),
    ({**GOOD_PROBE, "force": 1.0}, "(missing [], 1 extra)"),
    ("probe", "probe must be a map with keys ['at', 'depth', 'radius'], got a string 'probe'"),
    (None, "got null"),
]


@pytest.mark.parametrize(("item", "says"), BAD_LOADS)
def test_a_load_map_of_the_wrong_form_is_refused_in_one_short_line(item: Any, says: str) -> None:
    with pytest.raises(LiveInputError) as caught:
        Load.from_wire(item, 2)
    _short(caught, says)


@pytest.mark.parametrize(("item", "says"), BAD_PROBES)
def test_a_probe_map_of_the_wrong_form_is_refused_in_one_short_line(item: Any, says: str) -> None:
    with pytest.raises(LiveInputError) as caught:
        Probe.from_wire(item, 2)
    _short(caught, says)


def _short(caught: pytest.ExceptionInfo[LiveInputError], says: str) -> None:
    message = str(caught.value)
    assert says in message, message
    assert "\n" not in message and len(message) <= protocol.MAX_ERROR_CHARS
    assert isinstance(caught.value, UserError)


def test_a_long_value_is_quoted_at_most_64_characters() -> None:
    for item in ({**GOOD_PROBE, "depth": "x" * 10_000}, {**GOOD_PROBE, "at": [0.5, "x" * 10_000]}):
        with pytest.raises(LiveInputError) as caught:
            Probe.from_wire(item, 2)
        message = str(caught.value)
        assert "x" * 64 in message and "x" * 65 not in message and len(message) < 160


@pytest.mark.parametrize(
    "values",
    [
        # In form, whatever the engine makes of them: their ranges are the engine's to check
        # (tests/models/test_live_loads.py; tests/server/test_live_schema_bounds.py end to end).
        {"radius": 0.0}, {"radius": 1e-3}, {"radius": -0.1}, {"radius": 1e-310},
        {"radius": 5e-324}, {"radius": 1e9}, {"at": [1.2, 0.5]}, {"force": 1e308},
        {"force": -1e7},
    ],
)  # fmt: skip
def test_values_out_of_range_pass_the_schema_as_they_are(values: dict[str, Any]) -> None:
    item = {**GOOD_LOAD, **values}
    load = Load.from_wire(item, 2)
    assert load.to_wire() == item and load == (tuple(item["at"]), item["force"], item["radius"])


def test_ints_become_floats_and_a_string_may_give_a_bare_number() -> None:
    load = Load.from_wire({"at": [0, 1], "force": 2**63, "radius": 1}, 2)
    assert load == Load((0.0, 1.0), 9.223372036854776e18, 1.0)
    assert all(type(x) is float for x in (*load.at, load.force, load.radius))
    assert Load.from_wire({"at": 0.4, "force": 0.2, "radius": 0}, 1) == Load((0.4,), 0.2, 0.0)
    assert Probe.from_wire({"at": [0.4], "depth": 0, "radius": 0.0}, 1).at == (0.4,)
    with pytest.raises(LiveInputError, match="1 number, got True"):
        Probe.from_wire({"at": True, "depth": 0.0, "radius": 0.0}, 1)


def test_items_are_named_by_their_index_in_a_step() -> None:
    good = [Load((0.2, 0.2), 1.0, 0.05).to_wire()]
    assert loads_from_wire(good * 2, 2) == (Load((0.2, 0.2), 1.0, 0.05),) * 2
    with pytest.raises(LiveInputError, match=r"^load 1 force must be a number"):
        loads_from_wire([*good, {**GOOD_LOAD, "force": "1"}], 2)
    with pytest.raises(LiveInputError, match=r"^probe 2 needs exactly the keys"):
        probes_from_wire([GOOD_PROBE, GOOD_PROBE, {}], 2)
    assert probes_from_wire([], 2) == ()


def test_to_wire_and_from_wire_are_inverse_and_keep_the_key_order() -> None:
    load, probe = Load((0.3, 0.6), -0.5, 0.08), Probe((0.5,), 1e-3, 0.0)
    assert list(load.to_wire()) == list(LOAD_KEYS) and list(probe.to_wire()) == list(PROBE_KEYS)
    assert Load.from_wire(load.to_wire(), 2) == load
    assert Probe.from_wire(probe.to_wire(), 1) == probe
    assert Probe((np.float64(0.5), 1), 1e-3, 0.05).to_wire()["at"] == [0.5, 1.0]
    assert type(Probe((np.float64(0.5), 1), 1e-3, 0.05).to_wire()["at"][1]) is float
    # the bytes a step's probe had before the schema owned it
    expected = encode({"at": [0.5, 0.5], "depth": 1e-3, "radius": 0.05})
    assert encode(Probe((0.5, 0.5), 1e-3, 0.05).to_wire()) == expected


def test_a_reading_both_ways_a_newer_servers_fields_ignored() -> None:
    reading = ProbeReading(27.1, -1e-3, 0.0, True, False, 2e-5, 3e-3)
    wire = reading.to_wire()
    keys = ["force", "displacement", "gap", "in_contact", "outside", "compliance"]
    assert list(wire) == [*keys, "static_compliance"]  # next_free only when asked for
    back = ProbeReading.from_wire(wire)
    assert back[:7] == reading[:7] and math.isnan(back.next_free)
    ahead = reading._replace(next_free=-4e-4)
    assert ProbeReading.from_wire({**ahead.to_wire(), "stiffness": 0.1}) == ahead
    older = ProbeReading.from_wire({k: wire[k] for k in keys[:5]})  # a server before them
    assert older[:5] == reading[:5] and all(math.isnan(v) for v in older[5:])
    outside = ProbeReading.from_wire({**wire, "displacement": math.nan, "outside": True})
    assert outside.outside and math.isnan(outside.displacement)
    for bad in ({**wire, "in_contact": 1}, {**wire, "force": "1"}, {"force": 0.0}, [1, 2]):
        with pytest.raises(ProtocolError):
            ProbeReading.from_wire(bad)


def test_the_step_reply_in_the_servers_order_and_back() -> None:
    z = np.arange(6, dtype=np.float64).reshape(2, 3)
    readings = (ProbeReading(1.0, -0.1, 0.0, True, False),)
    reply = LiveStepReply("s", 3, 0.003, "abc", readings, z, "tok")
    fields = reply.to_reply_fields()
    assert list(fields) == ["session", "k", "t", "revision", "probes", "z", "token"]
    assert fields["z"] == pack_array(z, "<f4") and fields["probes"] == [readings[0].to_wire()]
    back = LiveStepReply.from_reply(fields)
    assert (back.session, back.k, back.t, back.revision, back.probes, back.token) == (
        "s", 3, 0.003, "abc", readings, "tok"
    )  # fmt: skip
    assert back.z is not None and back.z.dtype == np.float32 and back.z.shape == (2, 3)
    np.testing.assert_array_equal(back.z, z)
    haptic = LiveStepReply("s", 4, 0.004, "abc", ()).to_reply_fields()
    assert list(haptic) == ["session", "k", "t", "revision", "probes"]  # no frame, no token
    assert LiveStepReply.from_reply(haptic).z is None


@pytest.mark.parametrize(
    "change",
    [{"k": "1"}, {"k": 1.0}, {"t": None}, {"probes": {}}, {"probes": [{"force": 1.0}]},
     {"z": {"dtype": "<i4"}}],
)  # fmt: skip
def test_a_malformed_step_reply_is_a_protocol_error(change: dict[str, Any]) -> None:
    fields = {**LiveStepReply("s", 1, 0.001, "r", ()).to_reply_fields(), **change}
    with pytest.raises(ProtocolError, match="malformed live reply"):
        LiveStepReply.from_reply(fields)
    with pytest.raises(ProtocolError, match="malformed live reply"):
        LiveStepReply.from_reply({"session": "s", "t": 0.0, "probes": []})  # no k


def test_open_reset_and_close_replies() -> None:
    opened = OpenReply("s", "rev", displacement_residual=0.25, velocity_residual=0.0)
    fields = opened.to_reply_fields()
    assert fields == {"session": "s", "k": 0, "t": 0.0, "revision": "rev",
                      "residuals": {"displacement": 0.25, "velocity": 0.0}}  # fmt: skip
    assert list(fields) == ["session", "k", "t", "revision", "residuals"]
    assert list(fields["residuals"]) == list(live_schema.INITIAL_SHAPES)
    assert OpenReply.from_reply(fields) == opened
    with pytest.raises(ProtocolError, match="malformed open reply"):
        OpenReply.from_reply({**fields, "residuals": [0.25]})
    reset = ResetReply("s").to_reply_fields()
    assert list(reset) == ["session", "k", "t"] and ResetReply.from_reply(reset) == ResetReply("s")
    with pytest.raises(ProtocolError, match="malformed reset reply"):
        ResetReply.from_reply({"session": "s"})
    closed = CloseReply("s", False).to_reply_fields()
    assert closed == {"session": "s", "closed": False}
    assert CloseReply.from_reply(closed) == CloseReply("s", False)
    with pytest.raises(ProtocolError, match="malformed close reply"):
        CloseReply.from_reply({"session": "s", "closed": 0})


def test_initial_shapes_both_ways() -> None:
    assert Initial().to_wire() is None
    shape = np.linspace(0.0, 1e-3, 10)
    wire = Initial(velocity=shape).to_wire()
    assert wire == {"velocity": pack_array(shape, "<f4")}
    back = Initial.from_wire(wire)
    assert back.displacement is None and back.velocity is not None
    np.testing.assert_allclose(back.velocity, shape, rtol=1e-6)
    bad = {"displacement": {"dtype": "x" * 10_000, "shape": [1], "data": b""}}
    with pytest.raises(LiveInputError, match=r"^initial displacement: array dtype") as caught:
        Initial.from_wire(bad)
    assert len(str(caught.value)) < 200


def test_the_limits_have_one_definition() -> None:
    assert (MAX_LOADS, MAX_PROBES) == (64, 8)
    assert protocol.MAX_LOADS is MAX_LOADS and protocol.MAX_PROBES is MAX_PROBES
    assert (DEFAULT_MAX_FORCE, DEFAULT_MAX_DEPTH, DEFAULT_MAX_RADIUS) == (
        live_schema.MAX_FORCE, live_schema.MAX_DEPTH, live_schema.MAX_RADIUS
    )  # fmt: skip
    defaults = LiveLimits(2)
    assert (defaults.max_loads, defaults.max_probes) == (MAX_LOADS, MAX_PROBES)
    assert InvalidInput is LiveInputError
    step = {"v": 1, "id": 1, "op": "step", "session": "s", "k": 0}
    assert len(Request.from_wire(encode({**step, "loads": [GOOD_LOAD] * MAX_LOADS})).loads or [])
    with pytest.raises(RequestError, match=f"at most {MAX_LOADS}"):
        Request.from_wire(encode({**step, "loads": [GOOD_LOAD] * (MAX_LOADS + 1)}))
    with pytest.raises(RequestError, match=f"at most {MAX_PROBES}"):
        Request.from_wire(encode({**step, "probes": [GOOD_PROBE] * (MAX_PROBES + 1)}))


def test_live_limits_check_a_probes_wire_map_through_the_schema() -> None:
    limits = LiveLimits(2, min_radius=0.01)
    assert limits.probe_from_wire(GOOD_PROBE) == Probe((0.5, 0.5), 1e-5, 0.05)
    with pytest.raises(InvalidInput, match="probe needs exactly the keys"):
        limits.probe_from_wire({"at": [0.5, 0.5]})
    with pytest.raises(InvalidInput, match=r"probe depth must be in \[-1000, 0.001\]"):
        limits.probe_from_wire({**GOOD_PROBE, "depth": 0.002}, max_depth=1e-3)
    with pytest.raises(InvalidInput, match=r"probe radius must be in \[0.01, 10\]"):
        limits.probe_from_wire({**GOOD_PROBE, "radius": 0.001})


def _sent(message: dict[str, Any]) -> dict[str, Any]:
    """``message`` as the peer reads it (through msgpack)."""
    return decode(encode(message))


GOOD_TOOL = {"kind": "sphere", "at": [0.5, 0.5], "depth": 1e-3, "radius": 0.05}
BAD_TOOLS: list[tuple[Any, str]] = [
    ({**GOOD_TOOL, "kind": "cone"}, "tool kind must be 'sphere' or 'cylinder', got 'cone'"),
    ({**GOOD_TOOL, "kind": "Sphere"}, "got 'Sphere'"),
    ({**GOOD_TOOL, "kind": True}, "tool kind must be 'sphere' or 'cylinder', got a bool (True)"),
    ({**GOOD_TOOL, "kind": None}, "got null"),
    ({**GOOD_TOOL, "kind": ["sphere"]}, "got an array of 1"),
    ({**GOOD_TOOL, "kind": b"sphere"}, "got bytes"),
    ({**GOOD_TOOL, "depth": math.nan}, "tool depth must be finite"),
    ({**GOOD_TOOL, "radius": "0.05"}, "tool radius must be a number, got a string '0.05'"),
    ({**GOOD_TOOL, "at": [0.5]}, "tool at must be 2 numbers, got 1 value"),
    ({k: v for k, v in GOOD_TOOL.items() if k != "kind"}, "(missing ['kind'], 0 extra)"),
    ({**GOOD_TOOL, "height": 0.0}, "needs exactly the keys ['at', 'depth', 'kind', 'radius']"),
    ("tool", "tool must be a map with keys ['at', 'depth', 'kind', 'radius'], got a string"),
]


@pytest.mark.parametrize(("item", "says"), BAD_TOOLS)
def test_a_tool_map_of_the_wrong_form_is_refused_in_one_short_line(item: Any, says: str) -> None:
    with pytest.raises(LiveInputError) as caught:
        Tool.from_wire(item, 2)
    _short(caught, says)


def test_a_tools_long_kind_is_quoted_at_most_64_characters() -> None:
    with pytest.raises(LiveInputError) as caught:
        tools_from_wire([GOOD_TOOL, {**GOOD_TOOL, "kind": "x" * 10_000}], 2)
    message = str(caught.value)
    assert message.startswith("tool 1 kind must be 'sphere' or 'cylinder', got 'xxx")
    assert "x" * 64 in message and "x" * 65 not in message and len(message) < 160


def test_a_tool_both_ways_in_the_key_order() -> None:
    tool = Tool("cylinder", (0.3, 0.6), -2e-3, 0.1)
    assert list(tool.to_wire()) == list(TOOL_KEYS) == ["kind", "at", "depth", "radius"]
    assert Tool.from_wire(tool.to_wire(), 2) == tool
    assert tools_from_wire([{**GOOD_TOOL, "at": 0.4, "depth": 0}], 1) == (
        Tool("sphere", (0.4,), 0.0, 0.05),
    )  # fmt: skip
    assert tools_from_wire([], 2) == ()
    assert TOOL_KINDS == ("sphere", "cylinder") and MAX_TOOLS == 4
    assert protocol.MAX_TOOLS is MAX_TOOLS


def test_a_tool_reading_both_ways_nan_gap_kept_a_newer_servers_fields_ignored() -> None:
    reading = ToolReading(3.5, (0.25, 0.5), 3, 7, 0.0, 1e-12)
    wire = reading.to_wire()
    assert list(wire) == ["force", "centre", "contacts", "points", "gap", "penetration"]
    assert wire["centre"] == [0.25, 0.5] and ToolReading.from_wire(wire) == reading
    assert ToolReading.from_wire({**wire, "kind": "sphere"}) == reading
    empty = ToolReading.from_wire(
        _sent(ToolReading(0.0, (0.5,), 0, 0, math.nan, math.nan).to_wire())
    )
    assert empty[:4] == (0.0, (0.5,), 0, 0) and math.isnan(empty.gap)
    assert math.isnan(empty.penetration)
    bad_counts = [{**wire, "contacts": 1.0}, {**wire, "points": True}, {"force": 1.0}, [1, 2]]
    bad_numbers = [{**wire, "centre": 0.5}, {**wire, "centre": ["0.5"]}, {**wire, "gap": None}]
    for bad in bad_counts + bad_numbers:
        with pytest.raises(ProtocolError, match="tool reading"):
            ToolReading.from_wire(bad)


def test_a_step_reply_carries_tools_only_when_the_step_had_some() -> None:
    tools = (ToolReading(1.0, (0.5, 0.5), 2, 5, 0.0, 0.0),)
    reply = LiveStepReply("s", 1, 0.001, "r", (), tools=tools)
    fields = reply.to_reply_fields()
    assert list(fields) == ["session", "k", "t", "revision", "probes", "tools"]
    assert LiveStepReply.from_reply(_sent(fields)).tools == tools
    plain = LiveStepReply("s", 1, 0.001, "r", ()).to_reply_fields()
    assert "tools" not in plain and LiveStepReply.from_reply(plain).tools == ()
    bad_replies: list[Any] = [{}, [{"force": 1.0}]]
    for bad in bad_replies:
        with pytest.raises(ProtocolError, match="malformed live reply"):
            LiveStepReply.from_reply({**plain, "tools": bad})


def test_a_steps_tools_are_sent_and_read_back_bounded_by_max_tools() -> None:
    step = Request(Op.STEP, 3, session="s", k=0, tools=[GOOD_TOOL])
    assert decode(step.to_wire())["tools"] == [GOOD_TOOL]
    assert Request.from_wire(step.to_wire()).tools == [GOOD_TOOL]
    without = Request(Op.STEP, 3, session="s", k=0).to_wire()
    assert "tools" not in decode(without) and Request.from_wire(without).tools == []
    wire = {"v": 1, "id": 1, "op": "step", "session": "s", "k": 0}
    assert Request.from_wire(encode({**wire, "tools": [GOOD_TOOL] * MAX_TOOLS})).tools
    for bad in ([GOOD_TOOL] * (MAX_TOOLS + 1), GOOD_TOOL, "sphere"):
        with pytest.raises(RequestError, match=f"'tools' must be a list of at most {MAX_TOOLS}"):
            Request.from_wire(encode({**wire, "tools": bad}))
