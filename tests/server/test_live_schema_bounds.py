"""The live schema and the engine, tied: every per-step limit the protocol states has one
definition (the client's ``live_schema``) and the engine's own copies equal it; each bad load,
probe or tool map is a ``bad_request`` through the dispatcher, whether its form (the schema) or
its value (the engine) is wrong; and the server hands the engine its own typed inputs."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import pytest

from membrane_client import live_limits, live_schema, protocol
from membrane_client.protocol import ErrorCode, decode, encode
from membrane_models.live import Grasp, LiveEngine, Load, ModalEngine, Probe, Tool, inputs
from membrane_models.live.interface import TOOL_KINDS
from membrane_server.dispatch import Dispatcher
from membrane_server.live import engine_inputs
from membrane_server.served import ServedScene
from membrane_server.sessions import SessionTable

LOAD = {"at": [0.5, 0.5], "force": 1.0, "radius": 0.05}
PROBE = {"at": [0.5, 0.5], "depth": 1e-5, "radius": 0.05}
TOOL = {"kind": "sphere", "at": [0.5, 0.5], "depth": 1e-5, "radius": 0.05}


@pytest.fixture(scope="module")
def membrane_live() -> ServedScene:
    return ServedScene.load("membrane-live")


def test_every_limit_has_one_definition_and_the_engine_agrees_with_it(
    membrane_live: ServedScene,
) -> None:
    pairs = {
        "MAX_LOADS": (inputs.MAX_LOADS, live_schema.MAX_LOADS),
        "MAX_PROBES": (inputs.MAX_PROBES, live_schema.MAX_PROBES),
        "MAX_GRASPS": (inputs.MAX_GRASPS, live_schema.MAX_GRASPS),
        "MAX_TOOLS": (inputs.MAX_TOOLS, live_schema.MAX_TOOLS),
        "TOOL_KINDS": (TOOL_KINDS, live_schema.TOOL_KINDS),
        "MAX_FORCE": (inputs.MAX_FORCE, live_schema.MAX_FORCE),
        "MAX_DEPTH": (inputs.MAX_DEPTH, live_schema.MAX_DEPTH),
        "MAX_RADIUS": (inputs.MAX_RADIUS, live_schema.MAX_RADIUS),
    }
    assert {name: a == b for name, (a, b) in pairs.items()} == dict.fromkeys(pairs, True)
    # the protocol and the client's bounds are the schema's objects, not copies
    assert protocol.MAX_LOADS is live_schema.MAX_LOADS
    assert protocol.MAX_PROBES is live_schema.MAX_PROBES
    assert protocol.MAX_GRASPS is live_schema.MAX_GRASPS
    assert protocol.MAX_TOOLS is live_schema.MAX_TOOLS
    assert live_limits.DEFAULT_MAX_FORCE is live_schema.MAX_FORCE
    assert live_limits.DEFAULT_MAX_DEPTH is live_schema.MAX_DEPTH
    assert live_limits.DEFAULT_MAX_RADIUS is live_schema.MAX_RADIUS
    # and what a served scene describes is the schema's
    live = membrane_live.describe()["live"]
    keys = ("max_loads", "max_probes", "max_grasps", "max_tools", "max_force", "max_depth")
    described = {key: live[key] for key in keys}
    assert described == {
        "max_loads": live_schema.MAX_LOADS,
        "max_probes": live_schema.MAX_PROBES,
        "max_grasps": live_schema.MAX_GRASPS,
        "max_tools": live_schema.MAX_TOOLS,
        "max_force": live_schema.MAX_FORCE,
        "max_depth": live_schema.MAX_DEPTH,
    }
    assert live["max_radius"] == live_schema.MAX_RADIUS and live["units"] == live_schema.STEP_UNITS


def _dispatcher(served: ServedScene) -> Dispatcher:
    dispatcher = Dispatcher([served], sessions=SessionTable())
    opened = {"v": 1, "id": 1, "op": "open", "session": "s", "token": "t"}
    assert decode(dispatcher.handle([encode(opened)]).reply)["ok"]
    return dispatcher


def _step(dispatcher: Dispatcher, k: int = 0, **fields: Any) -> dict[str, Any]:
    message = {"v": 1, "id": 2, "op": "step", "session": "s", "token": "t", "k": k, **fields}
    return decode(dispatcher.handle([encode(message)]).reply)


# Every bad map the engine checked when it took maps (its tests now pass its own types), end to
# end: (step fields, what the message says).
BAD_STEPS: list[tuple[dict[str, Any], str]] = [
    ({"loads": [{**LOAD, "force": math.nan}]}, "load 0 force must be finite"),
    ({"loads": [{**LOAD, "force": math.inf}]}, "finite"),
    ({"loads": [{**LOAD, "force": -math.inf}]}, "finite"),
    ({"loads": [{**LOAD, "at": [0.5, math.nan]}]}, "load 0 at must be finite"),
    ({"loads": [{**LOAD, "radius": 0.0}]}, "logarithmically singular"),
    ({"loads": [{**LOAD, "radius": 1e-3}]}, "smallest"),
    ({"loads": [{**LOAD, "radius": -0.1}]}, ">= 0"),
    ({"loads": [{**LOAD, "at": [1.2, 0.5]}]}, "outside the unit domain"),
    ({"loads": [{**LOAD, "at": [0.5]}]}, "load 0 at must be 2 numbers, got 1 value"),
    ({"loads": [{**LOAD, "force": "1"}]}, "number"),
    ({"loads": [{**LOAD, "force": True}]}, "number"),
    ({"loads": [{"at": [0.5, 0.5], "force": 1.0}]}, "keys"),
    ({"loads": [{**LOAD, "extra": 1}]}, "keys"),
    ({"loads": [[0.5, 0.5, 1.0]]}, "map"),
    ({"loads": [{**LOAD, "force": 1e308}]}, "at most 1e+06"),
    ({"loads": [{**LOAD, "force": 2**63}]}, "at most 1e+06"),
    ({"loads": [{**LOAD, "force": -1e7}]}, "at most 1e+06"),
    ({"loads": [{**LOAD, "radius": 1e-310}]}, "smallest"),
    ({"loads": [{**LOAD, "radius": 5e-324}]}, "smallest"),
    ({"loads": [{**LOAD, "radius": 1e9}]}, "at most 10"),
    ({"loads": [LOAD, {**LOAD, "force": "1"}]}, "load 1 force"),
    ({"probes": [{**PROBE, "depth": -1e308}]}, "depth must be in [-1000, 1000]"),
    ({"probes": [{**PROBE, "depth": math.nan}]}, "finite"),
    ({"probes": [{**PROBE, "depth": math.inf}]}, "finite"),
    ({"probes": [{**PROBE, "depth": 1e308}]}, "depth must be in [-1000, 1000]"),
    ({"probes": [{**PROBE, "at": [math.inf, 0.5]}]}, "finite"),
    ({"probes": [{**PROBE, "radius": 0.0}]}, "logarithmically singular"),
    ({"probes": [{**PROBE, "radius": 1e-3}]}, "smallest"),
    ({"probes": [{"at": [0.5, 0.5], "depth": 1e-5}]}, "keys"),
    ({"probes": ["probe"]}, "map"),
    ({"probes": [PROBE, PROBE, {**PROBE, "depth": True}]}, "probe 2 depth"),
    ({"loads": [LOAD] * (live_schema.MAX_LOADS + 1)}, f"at most {live_schema.MAX_LOADS}"),
    ({"probes": [PROBE] * (live_schema.MAX_PROBES + 1)}, f"at most {live_schema.MAX_PROBES}"),
    # a tool's form is the schema's, read before the engine steps
    ({"tools": [TOOL] * (live_schema.MAX_TOOLS + 1)}, "'tools' must be a list of at most 4"),
    (
        {"tools": [{**TOOL, "kind": "cone"}]},
        "tool 0 kind must be 'sphere' or 'cylinder', got 'cone'",
    ),
    ({"tools": [TOOL, {**TOOL, "kind": "x" * 10_000}]}, "tool 1 kind must be 'sphere' or"),
    ({"tools": [{**TOOL, "kind": 1}]}, "tool 0 kind must be 'sphere' or 'cylinder', got int"),
    ({"tools": [{k: v for k, v in TOOL.items() if k != "kind"}]}, "(missing ['kind'], 0 extra)"),
    ({"tools": [{**TOOL, "depth": math.nan}]}, "tool 0 depth must be finite"),
    ({"tools": [{**TOOL, "at": [0.5]}]}, "tool 0 at must be 2 numbers, got 1 value"),
    ({"tools": [{**TOOL, "at": [1.5, 0.5]}], "strict": True}, "tool 0: at (1.5, 0.5) lies outside"),
]


@pytest.mark.parametrize(("fields", "says"), BAD_STEPS)
def test_a_bad_load_or_probe_map_is_a_bad_request_that_changes_nothing(
    membrane_live: ServedScene, fields: dict[str, Any], says: str
) -> None:
    dispatcher = _dispatcher(membrane_live)
    reply = _step(dispatcher, **fields)
    assert reply["error"]["code"] == ErrorCode.BAD_REQUEST, reply
    assert says in reply["error"]["message"], reply
    assert len(reply["error"]["message"]) <= protocol.MAX_ERROR_CHARS
    assert dispatcher.sessions.require("s").k == 0
    assert _step(dispatcher, loads=[LOAD], probes=[PROBE])["k"] == 1  # the session steps on


def test_a_step_for_another_k_is_refused_before_its_items_are_read(
    membrane_live: ServedScene,
) -> None:
    dispatcher = _dispatcher(membrane_live)
    bad = {"probes": [{"at": "x"}]}
    assert _step(dispatcher, k=3, **bad)["error"]["code"] == ErrorCode.STEP_MISMATCH
    assert _step(dispatcher, k=0, **bad)["error"]["code"] == ErrorCode.BAD_REQUEST


class _Recording:
    """Wraps an engine and keeps what each step was given."""

    def __init__(self, engine: LiveEngine[Any]) -> None:
        self.engine = engine
        self.given: list[tuple[Sequence[Load], Sequence[Probe]]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.engine, name)

    def step(
        self, state: Any, loads: Sequence[Load] = (), probes: Sequence[Probe] = (), **kw: Any
    ) -> Any:
        self.given.append((loads, probes))
        return self.engine.step(state, loads, probes, **kw)


@pytest.mark.slow
def test_the_engine_is_given_its_own_types_with_the_wires_values(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    served = ServedScene.load("membrane-live")
    assert isinstance(served.live, ModalEngine)
    recording = _Recording(served.live)
    monkeypatch.setattr(served, "live", recording)
    dispatcher = _dispatcher(served)
    wire_load = {"at": [0.25, 1], "force": -2, "radius": 0.08}
    assert _step(dispatcher, loads=[wire_load], probes=[PROBE])["ok"]
    [(loads, probes)] = recording.given
    assert loads == (Load((0.25, 1.0), -2.0, 0.08),) and type(loads[0]) is Load
    assert probes == (Probe((0.5, 0.5), 1e-5, 0.05),) and type(probes[0]) is Probe
    assert all(type(x) is float for x in (*loads[0].at, loads[0].force, loads[0].radius))


def test_engine_inputs_convert_the_schemas_items_field_by_field() -> None:
    request = protocol.Request(
        "step", 1, "s", k=0,
        loads=[live_schema.Load((0.1, 0.2), 0.3, 0.4).to_wire()],
        probes=[live_schema.Probe((0.5, 0.6), 0.7, 0.8).to_wire()],
        grasps=[live_schema.Grasp((0.9, 0.1), -0.2, 0.3).to_wire()],
        tools=[live_schema.Tool("cylinder", (0.4, 0.5), 0.6, 0.7).to_wire()],
    )  # fmt: skip
    loads, probes, grasps, tools = engine_inputs(request, 2)
    assert loads == (Load((0.1, 0.2), 0.3, 0.4),)
    assert probes == (Probe((0.5, 0.6), 0.7, 0.8),)
    assert grasps == (Grasp((0.9, 0.1), -0.2, 0.3),)
    assert tools == (Tool("cylinder", (0.4, 0.5), 0.6, 0.7),) and type(tools[0]) is Tool
    assert engine_inputs(protocol.Request("step", 1, "s", k=0), 1) == ((), (), (), ())
