"""The batch script (batch_script.lua) run in a real Lua 5.3, the Lua CoppeliaSim 4.6-4.10
embed, with a mock ``sim`` table; and the stand-in's Python stand-in for it checked against it.

lupa (the ``dev`` extra) embeds the interpreters, so these tests run wherever the suite does.
"""

from __future__ import annotations

from typing import Any

import pytest
from lupa import lua53

from membrane_coppelia.batch_script import BATCH_FUNCTION, BATCH_SCRIPT
from membrane_coppelia.standin import FakeScene

MOCK_SIM = """
local sim = {handle_world = -1, calls = {}}
function sim.setObjectPosition(handle, position, frame)
    sim.calls[#sim.calls + 1] = {handle, position[1], position[2], position[3], frame}
end
package.preload['sim'] = function() return sim end
return sim
"""


def _runtime() -> Any:
    lua = lua53.LuaRuntime(unpack_returned_tuples=True)
    assert lua.eval("_VERSION") == "Lua 5.3"
    return lua


def _compile(lua: Any, text: str) -> tuple[Any, Any]:
    """Lua's own ``load``: (the chunk, False) or (False, the error message)."""
    load = lua.eval(
        "function(s) local f, e = load(s, '=batch_script.lua'); return f or false, e or false end"
    )
    chunk, error = load(text)
    return chunk, error


def _lua_with(sim_source: str) -> tuple[Any, Any]:
    """A fresh Lua 5.3 with ``require('sim')`` answering the table ``sim_source`` returns, and
    the batch script loaded in it."""
    lua = _runtime()
    sim = lua.execute(sim_source)
    chunk, error = _compile(lua, BATCH_SCRIPT)
    assert error is False, error
    chunk()
    return lua, sim


def _calls(sim: Any) -> list[tuple[Any, ...]]:
    return [tuple(call[i] for i in range(1, 6)) for call in sim.calls.values()]


def test_the_script_compiles_in_lua_53() -> None:
    lua = _runtime()
    chunk, error = _compile(lua, BATCH_SCRIPT)
    assert error is False and chunk is not False
    broken, message = _compile(lua, BATCH_SCRIPT + "\nend end")
    assert broken is False and "batch_script.lua" in message  # the check can fail


def test_the_function_moves_every_handle_relative_to_the_frame() -> None:
    lua, sim = _lua_with(MOCK_SIM)
    move = lua.globals()[BATCH_FUNCTION]
    handles = lua.table_from([10, 11])
    xyz = lua.table_from([1.5, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert move(handles, xyz, 7) == 2
    assert _calls(sim) == [(10, 1.5, 2.0, 3.0, 7), (11, 4.0, 5.0, 6.0, 7)]


def test_without_a_frame_positions_are_in_the_world() -> None:
    lua, sim = _lua_with(MOCK_SIM)
    assert lua.globals()[BATCH_FUNCTION](lua.table_from([12]), lua.table_from([7, 8, 9])) == 1
    assert _calls(sim) == [(12, 7, 8, 9, -1)]


def test_an_empty_call_moves_nothing_and_answers_0() -> None:
    lua, sim = _lua_with(MOCK_SIM)  # the adapter's check that the script is ready
    assert lua.globals()[BATCH_FUNCTION](lua.table(), lua.table(), 3) == 0
    assert _calls(sim) == []


def test_mismatched_lengths_raise_a_lua_error() -> None:
    lua, sim = _lua_with(MOCK_SIM)
    move = lua.globals()[BATCH_FUNCTION]
    with pytest.raises(
        lua53.LuaError, match="membraneSetPositions: 2 handles need 6 coordinates, got 3"
    ):
        move(lua.table_from([10, 11]), lua.table_from([1.0, 2.0, 3.0]), 7)
    assert _calls(sim) == []  # checked before moving anything


def test_the_standins_python_version_does_what_the_lua_does() -> None:
    """The stand-in serves the function in Python: the same moves on twin scenes must agree."""
    by_lua, by_python = FakeScene(), FakeScene()
    for scene in (by_lua, by_python):
        frame = scene.create_dummy(0.05)
        scene.set_position(frame, [0.5, -1.0, 2.0], -1)
        handles = [scene.create_primitive_shape(4, [0.05] * 3) for _ in range(4)]
        scene.set_parent(handles[1], frame, True)  # a parent other than the frame, too
    xyz = [0.1 * i for i in range(12)]

    lua = _runtime()
    sim = lua.execute(
        "local sim = {handle_world = -1}; package.preload['sim'] = function() return sim end; "
        "return sim"
    )

    def set_object_position(handle: int, position: Any, relative_to: int) -> None:
        by_lua.set_position(handle, [float(v) for v in position.values()], relative_to)

    sim.setObjectPosition = set_object_position
    chunk, error = _compile(lua, BATCH_SCRIPT)
    assert error is False
    chunk()
    moved = lua.globals()[BATCH_FUNCTION](lua.table_from(handles), lua.table_from(xyz), frame)
    assert moved == by_python._batch_set_positions(handles, xyz, frame) == 4
    for handle in handles:
        assert by_lua.world_position(handle) == pytest.approx(by_python.world_position(handle))
    assert by_python.world_position(handles[3]) == pytest.approx((0.5 + 0.9, -1.0 + 1.0, 3.1))
