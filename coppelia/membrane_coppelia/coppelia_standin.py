"""A stand-in for CoppeliaSim's ZeroMQ remote API server, for tests and benchmarks.

It speaks version 2 of the remote API protocol, the one ``coppeliasim-zmqremoteapi-client``
2.0.4 uses, so that the real client talks to it unmodified:

- a REP socket; every message is one CBOR map;
- requests ``{"func": NAME, "args": [...], "argsL": n, "uuid": ...}`` (the first also carries
  ``ver``, ``lang`` and ``timeout``); replies ``{"ret": [values]}`` or ``{"err": message}``;
- ``zmqRemoteApi.require`` / ``zmqRemoteApi.info`` for ``sim``: the info reply maps each
  function name to ``{"func": {}}`` and each constant to ``{"const": value}``;
- ``sim.step()`` answers ``{"func": "_*wait*_"}``; the client answers ``_*executed*_`` and gets
  the final ``{"ret": []}``; the simulation advances one time step in between.

Behind it, :class:`FakeScene` records what a lattice driver does to a scene: objects (handles,
kinds, aliases, parents, sizes, colours, integer parameters), positions, simulation state and time
(advancing by ``dt`` on each step while running), the stepping level and script objects. Frames
carry translations only (the fake scene has no orientations). Like CoppeliaSim, stopping the
simulation restores the positions objects had at its start; the scene keeps the positions at the
moment of the stop in :attr:`FakeScene.positions_at_stop` for inspection.

The stand-in cannot run Lua: a script function is served by a Python implementation registered
under its name (the lattice script's :data:`~membrane_coppelia.coppelia_lua.BATCH_FUNCTION`), and
only when the script's text defines a function of that name.

It measures round trips and our own overhead, nothing of CoppeliaSim's own cost.

Run it alone with ``python -m membrane_coppelia.coppelia_standin --port 23000``.
"""

from __future__ import annotations

import argparse
import logging
import re
import signal
import sys
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

import cbor2
import zmq

from membrane_coppelia.coppelia_lua import BATCH_FUNCTION

__all__ = [
    "PROTOCOL_VERSION",
    "SIM_CONSTANTS",
    "CallRefused",
    "CoppeliaStandin",
    "FakeObject",
    "FakeScene",
    "RemoteApiProtocol",
    "main",
]

log = logging.getLogger(__name__)

PROTOCOL_VERSION = 2
WAIT = "_*wait*_"
EXECUTED = "_*executed*_"
END = "_*end*_"

# The subset of CoppeliaSim's `sim` constants that the lattice driver uses, with CoppeliaSim's
# values. A real server sends several thousand; clients must read them from the info map.
SIM_CONSTANTS: dict[str, int] = {
    "handle_world": -1,
    "handle_all": -2,
    "handle_parent": -11,
    "primitiveshape_plane": 1,
    "primitiveshape_disc": 2,
    "primitiveshape_cuboid": 3,
    "primitiveshape_spheroid": 4,
    "primitiveshape_cylinder": 5,
    "primitiveshape_cone": 6,
    "primitiveshape_capsule": 7,
    "shapeintparam_static": 3003,
    "shapeintparam_respondable": 3004,
    "colorcomponent_ambient_diffuse": 0,
    "colorcomponent_emission": 3,
    "scripttype_main": 0,
    "scripttype_simulation": 1,
    "scripttype_childscript": 1,
    "scripttype_addon": 2,
    "scripttype_customization": 6,
    "simulation_stopped": 0,
    "simulation_paused": 8,
    "simulation_advancing": 16,
    "simulation_advancing_running": 17,
    "floatparam_simulation_time_step": 1,
}
_C = SIM_CONSTANTS
_SHAPE_INT_PARAMS = {_C["shapeintparam_static"], _C["shapeintparam_respondable"]}
_PRIMITIVES = range(_C["primitiveshape_plane"], _C["primitiveshape_capsule"] + 1)


class CallRefused(Exception):
    """A call the fake scene refuses, as CoppeliaSim would; sent back as an ``err`` reply."""


Vec3 = tuple[float, float, float]


@dataclass
class FakeObject:
    """One object of the fake scene. ``position`` is relative to the parent (-1: the world)."""

    handle: int
    kind: str  # "shape", "dummy" or "script"
    alias: str
    parent: int = -1
    position: Vec3 = (0.0, 0.0, 0.0)
    primitive: int | None = None
    size: Vec3 | None = None
    colors: dict[int, Vec3] = field(default_factory=dict)
    int_params: dict[int, int] = field(default_factory=dict)
    script_type: int | None = None
    script_text: str = ""
    script_lang: str = ""
    script_enabled: bool = True
    script_initialized: bool = False


def _vec3(value: object, what: str) -> Vec3:
    if type(value) is list and len(value) == 3:  # the common case, checked fast
        x, y, z = value
        if type(x) is float and type(y) is float and type(z) is float:
            return (x, y, z)
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise CallRefused(f"{what}: expected 3 numbers, got {value!r}")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        raise CallRefused(f"{what}: expected 3 numbers, got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _add(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


class FakeScene:
    """The state of a fake CoppeliaSim scene and the ``sim.*`` functions that act on it.

    Args:
        dt: the simulation time step in seconds (CoppeliaSim's default is 0.05).
        scripts: offer ``sim.createScript``, ``sim.initScript`` and ``sim.callScriptFunction``
            (CoppeliaSim 4.6+); ``False`` plays an older version without them.
    """

    def __init__(self, dt: float = 0.05, *, scripts: bool = True) -> None:
        if not dt > 0.0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.dt = dt
        self.scripts = scripts
        self.objects: dict[int, FakeObject] = {}
        self.state = _C["simulation_stopped"]
        self.step_count = 0
        self.stepping_level = 0
        self.positions_at_stop: dict[int, Vec3] = {}
        self.calls: Counter[str] = Counter()
        self._next_handle = 10
        self._positions_at_start: dict[int, Vec3] = {}

    # -- what tests look at ------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """Whether the simulation is started (and not stopped)."""
        return self.state != _C["simulation_stopped"]

    @property
    def time(self) -> float:
        """Simulation time: steps taken times dt (a product, so it does not drift)."""
        return self.step_count * self.dt

    def world_position(self, handle: int) -> Vec3:
        """Position of an object in world coordinates."""
        obj = self._get(handle)
        if obj.parent == -1:
            return obj.position
        return _add(self.world_position(obj.parent), obj.position)

    def children(self, handle: int) -> list[int]:
        """Handles of the objects whose parent is ``handle``, in creation order."""
        return [h for h, o in self.objects.items() if o.parent == handle]

    def of_kind(self, kind: str) -> list[FakeObject]:
        """All objects of one kind ("shape", "dummy" or "script"), in creation order."""
        return [o for o in self.objects.values() if o.kind == kind]

    # -- the sim.* functions -----------------------------------------------------------------

    def functions(self) -> dict[str, Callable[..., Any]]:
        """The ``sim`` functions this scene implements, by their CoppeliaSim names."""
        functions: dict[str, Callable[..., Any]] = {
            "getSimulationTime": lambda: self.time,
            "getSimulationTimeStep": lambda: self.dt,
            "getSimulationState": lambda: self.state,
            "startSimulation": self.start_simulation,
            "stopSimulation": self.stop_simulation,
            "setStepping": self.set_stepping,
            "getFloatParam": self.get_float_param,
            "setFloatParam": self.set_float_param,
            "createPrimitiveShape": self.create_primitive_shape,
            "createDummy": self.create_dummy,
            "createScript": self.create_script,
            "initScript": self.init_script,
            "callScriptFunction": self.call_script_function,
            "removeObjects": self.remove_objects,
            "getObjectsInTree": self.objects_in_tree,
            "setObjectAlias": self.set_alias,
            "getObjectAlias": lambda handle, options=-1: self._get(handle).alias,
            "setObjectParent": self.set_parent,
            "getObjectParent": lambda handle: self._get(handle).parent,
            "setObjectPosition": self.set_position,
            "getObjectPosition": self.get_position,
            "setShapeColor": self.set_shape_color,
            "setObjectInt32Param": self.set_int_param,
            "getObjectInt32Param": self.get_int_param,
        }
        if not self.scripts:
            for name in ("createScript", "initScript", "callScriptFunction"):
                del functions[name]
        return functions

    def start_simulation(self) -> int:
        if not self.running:
            self.state = _C["simulation_advancing_running"]
            self.step_count = 0
            self._positions_at_start = {h: o.position for h, o in self.objects.items()}
        return 1

    def stop_simulation(self, wait: bool = False) -> int:
        if self.running:
            self.positions_at_stop = {h: self.world_position(h) for h in self.objects}
            for handle, position in self._positions_at_start.items():
                if handle in self.objects:
                    self.objects[handle].position = position
            self.state = _C["simulation_stopped"]
            self.step_count = 0
        # The remote API server resets every client's stepping when the simulation stops.
        self.stepping_level = 0
        return 1

    def set_stepping(self, enabled: bool) -> int:
        previous = self.stepping_level
        if enabled:
            self.stepping_level += 1
        elif self.stepping_level > 0:
            self.stepping_level -= 1
        return previous

    def advance(self) -> None:
        """One simulation step (the effect of ``sim.step()`` while the simulation runs)."""
        if self.running:
            self.step_count += 1

    def get_float_param(self, param: int) -> float:
        if param != _C["floatparam_simulation_time_step"]:
            raise CallRefused(f"unsupported float parameter {param}")
        return self.dt

    def set_float_param(self, param: int, value: float) -> int:
        if param != _C["floatparam_simulation_time_step"]:
            raise CallRefused(f"unsupported float parameter {param}")
        if self.running:
            raise CallRefused("the time step cannot change while the simulation runs")
        if not isinstance(value, int | float) or not value > 0.0:
            raise CallRefused(f"invalid time step {value!r}")
        self.dt = float(value)
        return 1

    def create_primitive_shape(self, primitive: int, sizes: list[float], options: int = 0) -> int:
        if primitive not in _PRIMITIVES:
            raise CallRefused(f"invalid primitive type {primitive!r}")
        size = _vec3(sizes, "sizes")
        if min(size) <= 0.0:
            raise CallRefused(f"sizes must be positive, got {list(size)}")
        return self._add_object("shape", "Shape", primitive=primitive, size=size)

    def create_dummy(self, size: float, color: object = None) -> int:
        if not isinstance(size, int | float) or size <= 0.0:
            raise CallRefused(f"invalid dummy size {size!r}")
        return self._add_object("dummy", "Dummy", size=(float(size),) * 3)

    def create_script(self, script_type: int, text: str, options: int = 0, lang: str = "") -> int:
        if script_type not in (_C["scripttype_simulation"], _C["scripttype_customization"]):
            raise CallRefused(f"unsupported script type {script_type!r}")
        if not isinstance(text, str):
            raise CallRefused("the script text must be a string")
        if lang not in ("", "lua", "python"):
            raise CallRefused(f"unknown script language {lang!r}")
        return self._add_object(
            "script",
            "Script",
            script_type=script_type,
            script_text=text,
            script_lang=lang or "lua",
            script_enabled=not (options & 1),
        )

    def init_script(self, handle: int) -> bool:
        script = self._get_script(handle)
        script.script_initialized = script.script_enabled
        return script.script_initialized

    def call_script_function(self, name: str, handle: int, *args: Any) -> Any:
        if not isinstance(name, str) or not isinstance(handle, int):
            raise CallRefused("expected sim.callScriptFunction(functionName, scriptHandle, ...)")
        script = self._get_script(handle)
        if not (script.script_enabled and script.script_initialized):
            raise CallRefused(f"script {handle} is not initialized")
        defined = re.search(rf"^\s*function\s+{re.escape(name)}\s*\(", script.script_text, re.M)
        if script.script_lang != "lua" or defined is None:
            raise CallRefused(f"function {name!r} does not exist in script {handle}")
        implementation = self._script_functions().get(name)
        if implementation is None:
            raise CallRefused(f"the stand-in has no Python implementation of {name!r}")
        return implementation(*args)

    def remove_objects(self, handles: list[int]) -> None:
        if not isinstance(handles, list):
            raise CallRefused("removeObjects expects a list of handles")
        removed = set(handles)
        for handle in removed:
            self._get(handle)
        # Like CoppeliaSim, the children of a removed object stay, now attached to the world.
        for handle in removed:
            for child in self.children(handle):
                if child not in removed:
                    self._reparent(child, -1, keep_in_place=True)
        for handle in removed:
            del self.objects[handle]

    def objects_in_tree(self, base: int, object_type: int = -2, options: int = 0) -> list[int]:
        if base == _C["handle_world"] or base == -12:  # the scene: every object
            found = list(self.objects)
        else:
            self._get(base)
            found = [base]
            frontier = [base]
            while frontier:
                kids = self.children(frontier.pop(0))
                found.extend(kids)
                if not options & 2:
                    frontier.extend(kids)
            if options & 1:
                found.remove(base)
        return found

    def set_alias(self, handle: int, alias: str) -> None:
        if not isinstance(alias, str) or not alias:
            raise CallRefused(f"invalid alias {alias!r}")
        self._get(handle).alias = alias

    def set_parent(self, handle: int, parent: int, keep_in_place: bool = True) -> None:
        self._get(handle)
        if parent != -1:
            self._get(parent)
            ancestor = parent
            while ancestor != -1:
                if ancestor == handle:
                    raise CallRefused("an object cannot become its own descendant")
                ancestor = self.objects[ancestor].parent
        self._reparent(handle, parent, keep_in_place)

    def set_position(self, handle: int, *args: Any) -> None:
        # Current order (handle, position, relativeTo=-1); the server still accepts the old
        # order (handle, relativeTo, position).
        if len(args) == 2 and isinstance(args[0], int) and isinstance(args[1], list):
            args = (args[1], args[0])
        if len(args) not in (1, 2):
            raise CallRefused("expected sim.setObjectPosition(handle, position, relativeTo)")
        position = _vec3(args[0], "position")
        relative_to = args[1] if len(args) == 2 else -1
        world = _add(self._frame_origin(handle, relative_to), position)
        obj = self._get(handle)
        obj.position = world if obj.parent == -1 else _sub(world, self.world_position(obj.parent))

    def get_position(self, handle: int, relative_to: int = -1) -> list[float]:
        origin = self._frame_origin(handle, relative_to)
        return list(_sub(self.world_position(handle), origin))

    def set_shape_color(
        self, handle: int, color_name: object, component: int, rgb: list[float]
    ) -> None:
        shape = self._get(handle)
        if shape.kind != "shape":
            raise CallRefused(f"object {handle} is not a shape")
        shape.colors[int(component)] = _vec3(rgb, "rgbData")

    def set_int_param(self, handle: int, param: int, value: int) -> None:
        obj = self._get(handle)
        if param in _SHAPE_INT_PARAMS and obj.kind != "shape":
            raise CallRefused(f"parameter {param} applies to shapes only")
        obj.int_params[int(param)] = int(value)

    def get_int_param(self, handle: int, param: int) -> int:
        obj = self._get(handle)
        if param not in obj.int_params:
            raise CallRefused(f"parameter {param} is not set on object {handle}")
        return obj.int_params[param]

    # -- the lattice script's function, in Python --------------------------------------------

    def _script_functions(self) -> dict[str, Callable[..., Any]]:
        return {BATCH_FUNCTION: self._batch_set_positions}

    def _batch_set_positions(
        self, handles: list[int], xyz: list[float], frame: int | None = None
    ) -> int:
        """What ``membraneSetPositions`` in ``coppelia_batch.lua`` does."""
        if not isinstance(handles, list) or not isinstance(xyz, list):
            raise CallRefused(f"{BATCH_FUNCTION}: expected a list of handles and a list of floats")
        count = len(handles)
        if len(xyz) != 3 * count:
            raise CallRefused(
                f"{BATCH_FUNCTION}: {count} handles need {3 * count} coordinates, got {len(xyz)}"
            )
        relative_to = _C["handle_world"] if frame is None else frame
        if relative_to == _C["handle_parent"]:  # a different frame per object: the long way
            for i, handle in enumerate(handles):
                self.set_position(handle, xyz[3 * i : 3 * i + 3], relative_to)
            return count
        # The same frame for every object: find its origin (and each parent's) once, so that the
        # stand-in's own work stays small beside the round trip being measured.
        origin = self._frame_origin(-1, relative_to)
        parent_origins: dict[int, Vec3] = {-1: (0.0, 0.0, 0.0)}
        ox, oy, oz = origin
        for i, handle in enumerate(handles):
            obj = self._get(handle)
            x, y, z = _vec3(xyz[3 * i : 3 * i + 3], f"position {i}")
            parent = obj.parent
            if parent not in parent_origins:
                parent_origins[parent] = self.world_position(parent)
            px, py, pz = parent_origins[parent]
            obj.position = (ox + x - px, oy + y - py, oz + z - pz)
        return count

    # -- helpers -----------------------------------------------------------------------------

    def _add_object(self, kind: str, alias: str, **attributes: Any) -> int:
        handle = self._next_handle
        self._next_handle += 1
        self.objects[handle] = FakeObject(handle=handle, kind=kind, alias=alias, **attributes)
        return handle

    def _get(self, handle: object) -> FakeObject:
        if not isinstance(handle, int) or handle not in self.objects:
            raise CallRefused(f"object does not exist: {handle!r}")
        return self.objects[handle]

    def _get_script(self, handle: object) -> FakeObject:
        obj = self._get(handle)
        if obj.kind != "script":
            raise CallRefused(f"object {handle} is not a script")
        return obj

    def _frame_origin(self, handle: int, relative_to: object) -> Vec3:
        if relative_to == _C["handle_world"]:
            return (0.0, 0.0, 0.0)
        if relative_to == _C["handle_parent"]:
            parent = self._get(handle).parent
            return (0.0, 0.0, 0.0) if parent == -1 else self.world_position(parent)
        if not isinstance(relative_to, int):
            raise CallRefused(f"invalid relativeTo {relative_to!r}")
        return self.world_position(relative_to)

    def _reparent(self, handle: int, parent: int, keep_in_place: bool) -> None:
        obj = self.objects[handle]
        world = self.world_position(handle)
        obj.parent = parent
        if keep_in_place:
            obj.position = world if parent == -1 else _sub(world, self.world_position(parent))


class RemoteApiProtocol:
    """Turns decoded remote API requests into replies, acting on a :class:`FakeScene`.

    No sockets here: :class:`CoppeliaStandin` feeds it requests and sends back what it returns.
    """

    def __init__(self, scene: FakeScene) -> None:
        self.scene = scene
        self._functions = scene.functions()
        self._required: set[str] = set()
        self._stepping_handshake = False  # between a step's _*wait*_ and its _*executed*_

    def reply(self, request: object) -> dict[str, Any]:
        """The reply to one request (never raises)."""
        if not isinstance(request, dict) or "uuid" not in request:
            # What CoppeliaSim answers to clients of an older protocol.
            return {
                "success": False,
                "error": "The client ZeroMQ remote API version does not match CoppeliaSim's",
            }
        if "ver" in request and request["ver"] != PROTOCOL_VERSION:
            return {"err": f"unsupported protocol version {request['ver']!r}"}
        func = request.get("func")
        args = request.get("args") or []
        if not isinstance(func, str) or not isinstance(args, list):
            return {"err": "a request needs 'func' (a string) and 'args' (an array)"}
        if self._stepping_handshake:
            return self._finish_step(func)
        if func == END:
            return {}
        self.scene.calls[func] += 1
        if func == "sim.step":
            self._stepping_handshake = True
            return {"func": WAIT, "args": []}
        try:
            return {"ret": _as_ret(self._call(func, args))}
        except CallRefused as exc:
            return {"err": f"{exc} (in function '{func}')"}
        except TypeError as exc:  # wrong number of arguments
            return {"err": f"invalid arguments: {exc} (in function '{func}')"}

    def _finish_step(self, func: str) -> dict[str, Any]:
        if func != EXECUTED:
            return {"err": f"expected {EXECUTED!r} during sim.step, got {func!r}"}
        self._stepping_handshake = False
        self.scene.advance()
        return {"ret": []}

    def _call(self, func: str, args: list[Any]) -> Any:
        if func == "zmqRemoteApi.require":
            return self._require(args)
        if func == "zmqRemoteApi.info":
            return self._info(args)
        module, _, name = func.partition(".")
        if module != "sim" or name not in self._functions:
            raise CallRefused(f"No such function: {func}")
        if module not in self._required:
            raise CallRefused(f"module {module!r} was not required")
        return self._functions[name](*args)

    def _require(self, args: list[Any]) -> None:
        if args != ["sim"]:
            raise CallRefused(f"module not found: {args!r} (the stand-in offers 'sim' only)")
        self._required.add("sim")

    def _info(self, args: list[Any]) -> dict[str, dict[str, Any]]:
        if args != ["sim"] or "sim" not in self._required:
            raise CallRefused(f"no such object: {args!r}")
        info: dict[str, dict[str, Any]] = {name: {"func": {}} for name in self._functions}
        info["step"] = {"func": {}}
        info.update({name: {"const": value} for name, value in SIM_CONSTANTS.items()})
        return info


def _as_ret(value: Any) -> list[Any]:
    if value is None:
        return []
    if isinstance(value, tuple):
        return list(value)
    return [value]


class CoppeliaStandin:
    """The stand-in server: a REP socket on 127.0.0.1 answering from its own thread.

    Args:
        host: interface to bind (loopback by default).
        port: TCP port; 0 picks a free one (see :attr:`address`).
        dt: the scene's initial simulation time step in seconds.
        answer_limit: stop answering (keep the socket, never reply) after this many replies;
            ``None`` answers forever. Simulates a CoppeliaSim that hangs.
        scripts: offer script objects (see :class:`FakeScene`).

    Use as a context manager, or call :meth:`start` and :meth:`stop`.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        dt: float = 0.05,
        answer_limit: int | None = None,
        scripts: bool = True,
    ) -> None:
        self.scene = FakeScene(dt, scripts=scripts)
        self.protocol = RemoteApiProtocol(self.scene)
        self.answer_limit = answer_limit
        self.replies = 0
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.REP)
        self._socket.setsockopt(zmq.LINGER, 0)
        if port == 0:
            self.port = self._socket.bind_to_random_port(f"tcp://{host}")
        else:
            self._socket.bind(f"tcp://{host}:{port}")
            self.port = port
        self.host = host
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> str:
        """The endpoint clients connect to."""
        return f"tcp://{self.host}:{self.port}"

    def start(self) -> CoppeliaStandin:
        """Serve from a background thread; returns self."""
        self._thread = threading.Thread(target=self.serve, name="coppelia-standin", daemon=True)
        self._thread.start()
        return self

    def stop_answering(self) -> None:
        """From now on receive nothing and reply to nothing (a hung CoppeliaSim)."""
        self.answer_limit = self.replies

    def request_stop(self) -> None:
        """Make :meth:`serve` return within about 50 ms (safe from a signal handler)."""
        self._stop.set()

    def stop(self) -> None:
        """Stop serving and close the socket."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._socket.close(linger=0)
        self._context.term()

    def __enter__(self) -> CoppeliaStandin:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def serve(self) -> None:
        """Answer requests until :meth:`stop` (or a signal) sets the stop flag."""
        poller = zmq.Poller()
        poller.register(self._socket, zmq.POLLIN)
        while not self._stop.is_set():
            if self.answer_limit is not None and self.replies >= self.answer_limit:
                self._stop.wait(0.05)  # hung: leave requests unanswered
                continue
            if not poller.poll(50):
                continue
            raw = self._socket.recv()
            self._socket.send(cbor2.dumps(self._reply(raw)))
            self.replies += 1

    def _reply(self, raw: bytes) -> dict[str, Any]:
        try:
            request = cbor2.loads(raw)
        except (cbor2.CBORDecodeError, ValueError) as exc:
            return {"err": f"cannot decode the request as CBOR: {exc}"}
        reply = self.protocol.reply(request)
        log.debug("%s -> %s", request.get("func") if isinstance(request, dict) else "?", reply)
        return reply


def main(argv: Sequence[str] | None = None) -> int:
    """Run the stand-in in the foreground until interrupted (SIGINT or SIGTERM)."""
    parser = argparse.ArgumentParser(
        prog="python -m membrane_coppelia.coppelia_standin",
        description="A stand-in for CoppeliaSim's ZeroMQ remote API (protocol 2), on loopback.",
    )
    parser.add_argument("--port", type=int, default=23000, help="TCP port; 0 picks a free one")
    parser.add_argument("--dt", type=float, default=0.05, help="initial simulation time step (s)")
    parser.add_argument(
        "--stop-answering-after",
        type=int,
        default=None,
        metavar="N",
        help="reply to N requests, then never again (simulates a hung CoppeliaSim)",
    )
    parser.add_argument(
        "--no-scripts",
        action="store_true",
        help="offer no script functions (plays a CoppeliaSim older than 4.6)",
    )
    args = parser.parse_args(argv)
    if not 0 <= args.port <= 65535:
        parser.error(f"--port must be in 0..65535, got {args.port}")
    if not args.dt > 0.0:
        parser.error(f"--dt must be > 0, got {args.dt}")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        standin = CoppeliaStandin(
            port=args.port,
            dt=args.dt,
            answer_limit=args.stop_answering_after,
            scripts=not args.no_scripts,
        )
    except zmq.ZMQError as exc:
        print(f"coppelia stand-in: cannot bind port {args.port}: {exc}", file=sys.stderr)
        return 2

    def _stop(signum: int, frame: FrameType | None) -> None:
        standin.request_stop()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    print(f"coppelia stand-in listening on {standin.address}", flush=True)
    standin.serve()
    standin.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
