"""Live sessions through the real dispatcher, in process: open, step, read, reset, close, and the
rules that keep a step from being applied twice and the sessions bounded."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from membrane_client import (
    Client,
    Grasp,
    GraspReading,
    Load,
    Probe,
    ServerError,
    Tool,
    ToolReading,
)
from membrane_client.protocol import (
    MAX_REQUEST_BYTES,
    ErrorCode,
    Op,
    Request,
    decode,
    pack_array,
)
from membrane_models.live import ENGINE_INPUTS, LiveEngine, ModalEngine
from membrane_models.live import Grasp as EngineGrasp
from membrane_models.live import Load as EngineLoad
from membrane_models.live import Probe as EngineProbe
from membrane_models.live import Tool as EngineTool
from membrane_models.live import ToolReading as EngineToolReading
from membrane_models.problems import make_problem
from membrane_server.dispatch import Dispatcher
from membrane_server.in_process import InProcessTransport
from membrane_server.scene import load_scene, scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.sessions import SessionTable

PROBE = Probe((0.5, 0.5), 0.0005, 0.05)


@pytest.fixture(scope="module")
def membrane_live() -> ServedScene:
    return ServedScene.load("membrane-live")


@pytest.fixture(scope="module")
def rope_live() -> ServedScene:
    return ServedScene.load("rope-live")


def _client(*scenes: ServedScene, sessions: SessionTable | None = None) -> Client:
    dispatcher = Dispatcher(list(scenes), sessions=sessions)
    return Client("in-process://live", transport=InProcessTransport(dispatcher))


def _code(refused: pytest.ExceptionInfo[ServerError]) -> str:
    return refused.value.code


def test_a_live_scene_describes_its_engine_and_still_answers_its_film(
    membrane_live: ServedScene,
) -> None:
    with _client(membrane_live) as client:
        info = client.describe()
        assert info.live["damping"] == 0.02 and info.live["hold"] == "zoh"
        assert info.live["max_loads"] == 64 and info.live["max_probes"] == 8
        assert info.live["modes_stepped"] > 0 and info.live["session_bytes"] > 0
        film = client.query(0.5)
    assert film.z.shape == (20, 20) and np.abs(film.z).max() > 0


def test_a_probe_pushes_the_tissue_and_feels_it(membrane_live: ServedScene) -> None:
    with _client(membrane_live) as client, client.session() as session:
        assert session.k == 0 and session.info is not None
        for _ in range(200):
            frame = session.step(probes=[PROBE], frame=False)
        assert frame.z is None and frame.k == 200 and math.isclose(frame.t, 0.2)
        reading = frame.probes[0]
        assert reading.in_contact and reading.force > 0 and reading.gap == 0.0
        assert reading.displacement == pytest.approx(-PROBE.depth, rel=1e-9)
        shown = session.frame()  # the display loop's read: the same state, with its frame
        assert shown.k == 200 and shown.z is not None and shown.z.shape == (20, 20)
        assert shown.z[10, 10] < 0 and shown.positions().shape == (400, 3)
        lifted = session.step()  # the probe lifts off: no reading, the tissue springs back
        assert lifted.probes == () and lifted.k == 201


def test_a_resent_step_gets_the_stored_reply_and_is_applied_once(
    membrane_live: ServedScene,
) -> None:
    dispatcher = Dispatcher([membrane_live])
    request = Request(Op.OPEN, 1, "s1")
    assert decode(dispatcher.handle([request.to_wire()]).reply)["ok"]
    step = Request(Op.STEP, 2, "s1", k=0, probes=[PROBE.to_wire()]).to_wire()
    first = dispatcher.handle([step]).reply
    again = dispatcher.handle([step]).reply  # the Lazy Pirate re-sends the same bytes
    assert again == first and decode(first)["k"] == 1
    assert dispatcher.sessions.require("s1").k == 1
    assert dispatcher.sessions.counts["resent"] == 1 and dispatcher.sessions.counts["steps"] == 1


@pytest.mark.parametrize(("k", "request_id"), [(0, 3), (1, 2), (2, 4), (5, 5)])
def test_any_other_step_is_a_mismatch_naming_the_sessions_count(
    membrane_live: ServedScene, k: int, request_id: int
) -> None:
    dispatcher = Dispatcher([membrane_live])
    dispatcher.handle([Request(Op.OPEN, 1, "s1").to_wire()])
    dispatcher.handle([Request(Op.STEP, 2, "s1", k=0).to_wire()])
    reply = decode(dispatcher.handle([Request(Op.STEP, request_id, "s1", k=k).to_wire()]).reply)
    if (k, request_id) == (1, 2):  # k = 1 is the next step: another id may take it
        assert reply["ok"] and reply["k"] == 2
        return
    assert reply["error"]["code"] == ErrorCode.STEP_MISMATCH
    assert "the next step is k = 1" in reply["error"]["message"]
    assert dispatcher.sessions.require("s1").k == 1


def test_two_clients_stepping_one_session_one_wins(membrane_live: ServedScene) -> None:
    dispatcher = Dispatcher([membrane_live])
    first = Client("a", transport=InProcessTransport(dispatcher))
    second = Client("b", transport=InProcessTransport(dispatcher))
    with first, second:
        mine = first.session()
        theirs = type(mine)(second, None, session_id=mine.id)  # joins without opening
        mine.step(probes=[PROBE])
        before = dispatcher.sessions.require(mine.id).state
        with pytest.raises(ServerError) as refused:
            theirs.step(probes=[Probe((0.2, 0.2), 0.01, 0.05)])  # it still believes k = 0
        assert _code(refused) == ErrorCode.STEP_MISMATCH
        assert dispatcher.sessions.require(mine.id).state is before  # state intact
        assert mine.step().k == 2


def test_bad_loads_are_refused_and_change_nothing(membrane_live: ServedScene) -> None:
    with _client(membrane_live) as client, client.session() as session:
        session.step(loads=[Load((0.3, 0.3), 0.01, 0.05)])
        before = session.frame().z
        bad_inputs: tuple[dict[str, Any], ...] = (
            {"loads": [{"at": [0.5, 0.5], "force": math.nan, "radius": 0.05}]},
            {"loads": [{"at": [0.5, 0.5], "force": 1.0, "radius": 0.0}]},  # a point, on a membrane
            {"probes": [{"at": [0.5, 0.5], "depth": -2e3, "radius": 0.05}]},
            {"probes": [{"at": [0.5], "depth": 1e-3, "radius": 0.05}]},
            {"loads": [{"at": [0.5, 0.5], "force": 1.0}]},  # no radius
        )
        for bad in bad_inputs:
            with pytest.raises(ServerError) as refused:
                session.step(**bad)
            assert _code(refused) == ErrorCode.BAD_REQUEST
        assert session.k == 1
        np.testing.assert_array_equal(session.frame().z, before)


def test_initial_shapes_are_projected_and_reported(rope_live: ServedScene) -> None:
    x = np.linspace(0.0, 1.0, 100)
    pluck = 1e-3 * np.sin(np.pi * x)
    with _client(rope_live) as client:
        with client.session(initial={"displacement": pluck}) as session:
            assert session.residuals["displacement"] < 1e-6
            assert session.residuals["velocity"] == 0.0
            z = session.frame().z
            assert z is not None
            np.testing.assert_allclose(z, pluck, atol=1e-9)
        kinked = np.minimum(x, 1.0 - x) * 1e-3  # a kink the kept modes carry only in part
        with client.session(initial={"displacement": kinked}) as session:
            assert 0.0 < session.residuals["displacement"] < 0.05
        with pytest.raises(ServerError) as refused:
            client.session(initial={"displacement": np.full(100, np.nan)})
        assert _code(refused) == ErrorCode.BAD_REQUEST
        with pytest.raises(ServerError) as refused:
            client.session(initial={"displacement": np.zeros(7)})
        assert _code(refused) == ErrorCode.BAD_REQUEST


def test_initial_shapes_of_the_largest_live_lattice_fit_in_one_request() -> None:
    shapes = {
        name: pack_array(np.zeros((100, 100)), "<f4") for name in ("displacement", "velocity")
    }
    request = Request(Op.OPEN, 2**62, "x" * 64, scene="x" * 64, initial=shapes)
    assert len(request.to_wire()) <= MAX_REQUEST_BYTES


def test_reset_returns_to_the_opened_state(membrane_live: ServedScene) -> None:
    with _client(membrane_live) as client, client.session() as session:
        at_rest = session.frame().z
        for _ in range(20):
            session.step(loads=[Load((0.5, 0.5), 0.01, 0.05)])
        session.reset()
        assert session.k == 0
        np.testing.assert_array_equal(session.frame().z, at_rest)
        assert session.step().k == 1


def test_refusals_name_their_cause(membrane_live: ServedScene) -> None:
    film = ServedScene.load("membrane")
    with _client(membrane_live, film) as client:
        with pytest.raises(ServerError) as refused:
            client.session("membrane")
        assert _code(refused) == ErrorCode.NOT_LIVE
        with pytest.raises(ServerError) as refused:
            client.request(Op.STEP, scene="membrane-live", session="never-opened", k=0)
        assert _code(refused) == ErrorCode.UNKNOWN_SESSION
        session = client.session("membrane-live")
        with pytest.raises(ServerError) as refused:
            client.request(Op.OPEN, scene="membrane-live", session=session.id)
        assert _code(refused) == ErrorCode.SESSION_EXISTS
        with pytest.raises(ServerError) as refused:
            client.request(Op.READ, scene="membrane", session=session.id)
        assert _code(refused) == ErrorCode.BAD_REQUEST  # the session is on another scene
        with pytest.raises(ServerError) as refused:
            client.request(Op.STEP, scene="membrane-live", k=0)  # the Client's id: not opened
        assert _code(refused) == ErrorCode.UNKNOWN_SESSION
        session.close()
        session.close()  # closing twice is harmless


def test_sessions_are_bounded_in_number_and_idle_time(membrane_live: ServedScene) -> None:
    now = [0.0]
    table = SessionTable(max_sessions=3, idle_s=10.0, clock=lambda: now[0])
    with _client(membrane_live, sessions=table) as client:
        sessions = [client.session() for _ in range(3)]
        with pytest.raises(ServerError) as refused:
            client.session()
        assert _code(refused) == ErrorCode.TOO_MANY_SESSIONS
        now[0] = 5.0
        sessions[0].step()  # used at 5 s: the others idle since 0 s
        now[0] = 12.0
        assert len(table) == 3
        with pytest.raises(ServerError) as refused:
            sessions[1].step()
        assert _code(refused) == ErrorCode.UNKNOWN_SESSION
        assert len(table) == 1 and sessions[0].step().k == 2
        client.session()  # room again
        stats = client.stats().live or {}
    assert stats["open"] == 2 and stats["expired"] == 2 and stats["refused"] == 1


def test_a_reload_keeps_open_sessions_on_their_engine(membrane_live: ServedScene) -> None:
    table = SessionTable()
    transport = InProcessTransport(Dispatcher([membrane_live], sessions=table))
    with Client("in-process://live", transport=transport) as client:
        session = client.session()
        session.step(probes=[PROBE])
        data = load_scene("membrane-live").model_dump(exclude={"source"})
        data["live"] = {"damping": 0.1}
        reloaded = ServedScene.load(scene_from_dict(data))
        transport.dispatcher = Dispatcher([reloaded], sessions=table)  # as Server.reload does
        reply = client.request(Op.STEP, session=session.id, k=1)
        assert reply["revision"] == membrane_live.revision != reloaded.revision
        assert client.describe(refresh=True).live["damping"] == 0.1
        fresh = client.session()
        assert client.request(Op.READ, session=fresh.id)["revision"] == reloaded.revision


def test_the_wire_session_follows_the_engine_exactly(membrane_live: ServedScene) -> None:
    """What a session serves is the engine's own answer, to float32 rounding of the frame."""
    engine = ModalEngine(make_problem("membrane-forced"), (20, 20), 0.001, damping=0.02, modes=60)
    state = engine.start().state
    plan = [([Load((0.3, 0.6), 0.02 * (k % 7), 0.05)], [PROBE]) for k in range(50)]
    with _client(membrane_live) as client, client.session() as session:
        for loads, probes in plan:
            own = [EngineLoad(*load) for load in loads], [EngineProbe(*probe) for probe in probes]
            result = engine.step(state, *own)
            state = result.state
            frame = session.step(loads, probes)  # on the wire, through the live schema
            assert frame.probes[0].force == result.probes[0].force
            assert frame.z is not None and result.frame is not None
            np.testing.assert_array_equal(frame.z.reshape(-1), result.frame.astype("<f4"))


def test_a_server_keeps_the_session_table_it_is_given() -> None:
    """An empty table is falsy (it has a length): the server must still use it, not a default."""
    from membrane_server.server import Server

    table = SessionTable(max_sessions=1, idle_s=5.0)
    server = Server(["membrane-live"], bind="tcp://127.0.0.1:*", sessions=table)
    assert server.sessions is table and server.dispatcher.sessions is table
    with Client("in-process://live", transport=InProcessTransport(server.dispatcher)) as client:
        client.session()
        with pytest.raises(ServerError) as refused:
            client.session()
        assert _code(refused) == ErrorCode.TOO_MANY_SESSIONS


def test_a_grasp_on_the_wire_is_the_engines_and_read_repeats_it(rope_live: ServedScene) -> None:
    """A grasp holds rope-live's x = 0.3 at 1e-3 beside a probe: the reply's readings are the
    engine's own for the same inputs, digit for digit, and ``read`` gives them again."""
    grasp, probe = Grasp((0.3,), 1e-3, 0.0), Probe((0.7,), 5e-4, 0.0)
    engine = rope_live.live
    assert engine is not None
    state = engine.start().state
    with _client(rope_live) as client, client.session("rope-live") as session:
        for _ in range(3):
            frame = session.step(probes=[probe], grasps=[grasp])
            expected = engine.step(
                state,
                [],
                [EngineProbe(*probe)],
                grasps=[EngineGrasp(*grasp)],  # type: ignore[call-arg]
            )
            state = expected.state
        held = expected.grasps[0]
        assert frame.grasps == (GraspReading(held.force, held.displacement, False),)
        assert held.displacement == pytest.approx(1e-3, rel=1e-10) and held.force > 0.0
        assert frame.probes[0].force == expected.probes[0].force
        assert session.frame().grasps == frame.grasps
        plain = session.step(probes=[probe])  # no grasps asked: none in the reply
        assert plain.grasps == ()
        with pytest.raises(ServerError, match="grasp 0: height must be in"):
            session.step(grasps=[{"at": [0.5], "height": 2e3, "radius": 0.0}])
        with pytest.raises(ServerError, match="'grasps' must be a list of at most 8"):
            session.step(grasps=[grasp] * 9)


class _ToolStandIn:
    """An engine that takes tools, until the engine's own land: it steps the wrapped engine
    without them, keeps each step's keywords, and reads tool i with force i + 1 at its centre."""

    def __init__(self, engine: LiveEngine[Any], inputs: frozenset[str] = ENGINE_INPUTS) -> None:
        self.engine, self.inputs = engine, inputs
        self.given: list[dict[str, Any]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.engine, name)

    def step(
        self,
        state: Any,
        loads: Sequence[EngineLoad] = (),
        probes: Sequence[EngineProbe] = (),
        **kw: Any,
    ) -> Any:
        self.given.append(dict(kw))
        tools: Sequence[EngineTool] = kw.pop("tools", ())
        result = self.engine.step(state, loads, probes, **kw)
        readings = tuple(
            EngineToolReading(float(i + 1), tool.at, 1, 2, 0.0, math.nan)
            for i, tool in enumerate(tools)
        )
        return dataclasses.replace(result, tools=readings)


def test_tools_reach_the_engine_as_its_own_and_their_readings_come_back(
    rope_live: ServedScene, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Tools on the wire (a stand-in engine reads them): the engine gets its own ``Tool``s and
    the ``tools`` keyword only when a step has some; the reply's readings are the engine's,
    ``read`` repeats them, ``reset`` clears them; a bad kind, a fifth tool and tools for an
    engine that takes none are refused (``strict`` on tools: test_live_schema_bounds)."""
    assert rope_live.live is not None
    stand_in = _ToolStandIn(rope_live.live)
    monkeypatch.setattr(rope_live, "live", stand_in)
    sphere, probe = Tool("sphere", (0.3,), 1e-3, 0.05), Probe((0.7,), 5e-4, 0.0)
    with _client(rope_live) as client, client.session("rope-live") as session:
        cylinder = {"kind": "cylinder", "at": [0.6], "depth": 0, "radius": 0.1}
        frame = session.step(tools=[sphere, cylinder])
        assert stand_in.given[-1]["tools"] == (
            EngineTool("sphere", (0.3,), 1e-3, 0.05), EngineTool("cylinder", (0.6,), 0.0, 0.1)
        )  # fmt: skip
        assert all(type(tool) is EngineTool for tool in stand_in.given[-1]["tools"])
        assert [reading[:5] for reading in frame.tools] == [
            (1.0, (0.3,), 1, 2, 0.0), (2.0, (0.6,), 1, 2, 0.0)
        ]  # fmt: skip
        assert all(type(r) is ToolReading and math.isnan(r.penetration) for r in frame.tools)
        assert [r[:5] for r in session.frame().tools] == [r[:5] for r in frame.tools]
        assert session.step(probes=[probe]).tools == () and "tools" not in stand_in.given[-1]
        session.step(tools=[sphere])
        session.reset()
        assert session.frame().tools == ()
        with pytest.raises(ServerError, match="tool 0 kind must be 'sphere' or 'cylinder'"):
            session.step(tools=[{**sphere.to_wire(), "kind": "cone"}])
        with pytest.raises(ServerError, match="'tools' must be a list of at most 4"):
            session.step(tools=[sphere] * 5)
        stand_in.inputs = frozenset({"loads", "probes"})
        with pytest.raises(ServerError, match="this scene's engine takes no tools"):
            session.step(tools=[sphere])
        assert session.k == 0
