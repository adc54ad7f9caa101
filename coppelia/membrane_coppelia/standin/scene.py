"""A fake CoppeliaSim scene: the state the stand-in keeps and the ``sim.*`` functions acting on it.

:class:`FakeScene` records what an adapter does to a scene: objects (handles, kinds, aliases,
parents, sizes, colours, shape flags), positions, scripts, float signals and scene properties,
and the simulation's state and time. Frames carry translations only (no orientations, physics or
rendering).

It plays one CoppeliaSim release at a time (``version``), offering the calls that release has
(docs/COPPELIA.md, "Versions", says where each was checked):

=========  ==============================================================================
 4.6       scripts are not scene objects: ``sim.addScript``, ``sim.setScriptStringParam``,
           ``sim.associateScriptWithObject``, ``sim.removeScript``; ``sim.setFloatParam``,
           ``sim.setObjectInt32Param``, ``sim.setFloatSignal``
 4.7       script objects: ``sim.createScript`` (aliased, parented, removed as objects)
 4.8, 4.9  plus the property calls: ``sim.setFloatProperty(sim.handle_scene, 'timeStep' |
           'signal.NAME', v)``, ``sim.setBoolProperty(shape, 'dynamic' | 'respondable', v)``
           (the older calls stay, deprecated)
=========  ==============================================================================

Behaviours copied from CoppeliaSim: the simulation stops over several passes (about to stop,
last before stop, then stopped) and restores the positions objects had at its start;
``sim.setFloatParam(sim.floatparam_simulation_time_step, dt)`` returns 0 without an error while
the simulation runs and clamps dt to [1e-4, 10]; ``sim.initScript`` returns nothing (and with
``init_delay_passes`` the script starts only that many passes later, as in the development line
after 4.10, where it became asynchronous); legacy float signals and ``signal.*`` properties are
separate stores (CoppeliaSim's ``sim.waitForSignal`` reads them in separate branches).

The stand-in cannot run Lua: a script function is served by a Python implementation registered
under its name (the lattice script's :data:`~membrane_coppelia.batch_script.BATCH_FUNCTION`),
and only when the script's text defines a function of that name. The Lua itself is run in a real
Lua 5.3 in the tests, and checked against this implementation.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from membrane_coppelia.batch_script import BATCH_FUNCTION

__all__ = [
    "RELEASES",
    "SIM_CONSTANTS",
    "CallRefused",
    "FakeObject",
    "FakeScene",
    "Release",
]

# CoppeliaSim's `sim` constants that the adapter uses. A real server sends several thousand;
# clients must read them from the info map.
SIM_CONSTANTS: dict[str, int] = {
    "handle_world": -1,
    "handle_all": -2,
    "handle_parent": -11,
    "handle_scene": -12,
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
    "simulation_advancing_firstafterstop": 16,
    "simulation_advancing_running": 17,
    "simulation_advancing_lastbeforepause": 19,
    "simulation_advancing_firstafterpause": 20,
    "simulation_advancing_abouttostop": 21,
    "simulation_advancing_lastbeforestop": 22,
    "floatparam_simulation_time_step": 1,
    "intparam_program_version": 0,
}
# 4.6's script calls' constants (the stand-in's values: the adapter reads them from the info map).
SIM_CONSTANTS_46: dict[str, int] = {
    "scripttype_customizationscript": 6,
    "scriptstringparam_text": 2,
}
_C = SIM_CONSTANTS
STOPPED = _C["simulation_stopped"]
FIRST_AFTER_STOP = _C["simulation_advancing_firstafterstop"]
RUNNING = _C["simulation_advancing_running"]
ABOUT_TO_STOP = _C["simulation_advancing_abouttostop"]
LAST_BEFORE_STOP = _C["simulation_advancing_lastbeforestop"]
MIN_DT, MAX_DT = 1e-4, 10.0
_SHAPE_INT_PARAMS = {_C["shapeintparam_static"], _C["shapeintparam_respondable"]}
_PRIMITIVES = range(_C["primitiveshape_plane"], _C["primitiveshape_capsule"] + 1)

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Release:
    """What one CoppeliaSim release offers, as far as the adapter is concerned."""

    name: str  # "4.9"
    number: int  # sim.intparam_program_version
    script_objects: bool  # sim.createScript (4.7+); else sim.addScript (4.6)
    properties: bool  # sim.set*Property (4.8+)


RELEASES: dict[str, Release] = {
    "4.6": Release("4.6", 40600, script_objects=False, properties=False),
    "4.7": Release("4.7", 40700, script_objects=True, properties=False),
    "4.8": Release("4.8", 40800, script_objects=True, properties=True),
    "4.9": Release("4.9", 40900, script_objects=True, properties=True),
}


class CallRefused(Exception):
    """A call the fake scene refuses, as CoppeliaSim would; sent back as an ``err`` reply."""


@dataclass
class FakeObject:
    """One object of the fake scene. ``position`` is relative to the parent (-1: the world).

    A 4.6 script is no scene object: its ``parent`` is the object it is associated with, and
    ``scene_object`` is False (object calls refuse its handle).
    """

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
    scene_object: bool = True
    init_in: int | None = None  # passes left before an asynchronous initScript takes effect


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


def _number(value: object, what: str) -> float:
    if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
        raise CallRefused(f"{what}: expected a number, got {value!r}")
    return float(value)


def _add(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


class FakeScene:
    """The state of a fake CoppeliaSim scene and the ``sim.*`` functions that act on it.

    Args:
        dt: the simulation time step in seconds (CoppeliaSim's default is 0.05).
        scripts: offer script calls; ``False`` plays a build without them (batched moves
            unavailable).
        version: the release played: "4.6", "4.7", "4.8" or "4.9" (see the module's table).
        init_delay_passes: passes before ``sim.initScript`` takes effect (0: at once, as
            through 4.10).
    """

    def __init__(
        self,
        dt: float = 0.05,
        *,
        scripts: bool = True,
        version: str = "4.9",
        init_delay_passes: int = 0,
    ) -> None:
        if not dt > 0.0:
            raise ValueError(f"dt must be > 0, got {dt}")
        if version not in RELEASES:
            raise ValueError(f"version must be one of {', '.join(RELEASES)}, got {version!r}")
        if init_delay_passes < 0:
            raise ValueError(f"init_delay_passes must be >= 0, got {init_delay_passes}")
        self.dt = dt
        self.scripts = scripts
        self.release = RELEASES[version]
        self.init_delay_passes = init_delay_passes
        self.objects: dict[int, FakeObject] = {}
        self.state = STOPPED
        self.step_count = 0
        self.stop_requested = False
        self.positions_at_stop: dict[int, Vec3] = {}
        self.signals: dict[str, float] = {}  # legacy float signals
        self.properties: dict[str, float] = {}  # the scene's signal.* properties
        self.calls: Counter[str] = Counter()
        self.animations: dict[int, Callable[[float], Vec3]] = {}
        self._next_handle = 10
        self._positions_at_start: dict[int, Vec3] = {}

    # -- what tests look at ------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """Whether the simulation is started (and not yet stopped)."""
        return self.state != STOPPED

    @property
    def time(self) -> float:
        """Simulation time: passes taken times dt (a product, so it does not drift)."""
        return self.step_count * self.dt

    def world_position(self, handle: int) -> Vec3:
        """Position of an object in world coordinates."""
        obj = self._get(handle, scripts=True)
        if obj.parent == -1 or not obj.scene_object:
            return obj.position
        return _add(self.world_position(obj.parent), obj.position)

    def children(self, handle: int) -> list[int]:
        """Handles of the objects whose parent is ``handle``, in creation order."""
        return [h for h, o in self.objects.items() if o.parent == handle and o.scene_object]

    def of_kind(self, kind: str) -> list[FakeObject]:
        """All objects of one kind ("shape", "dummy" or "script"), in creation order."""
        return [o for o in self.objects.values() if o.kind == kind]

    def animate(self, handle: int, path: Callable[[float], Vec3]) -> None:
        """Move an object along ``path(t)`` (world coordinates) while the simulation runs, as a
        script in the scene would (a robot's tool tip): set at the start and after each pass."""
        self._get(handle)
        self.animations[handle] = path

    # -- the simulation's passes (driven by the stand-in's add-on loop) -----------------------

    def end_pass(self) -> None:
        """End one simulation pass: time advances by dt; a requested stop proceeds."""
        if self.state == LAST_BEFORE_STOP:
            self._finish_stop()
            return
        if not self.running:
            return
        self.step_count += 1
        if self.stop_requested:
            self.state = LAST_BEFORE_STOP if self.state == ABOUT_TO_STOP else ABOUT_TO_STOP
        else:
            self.state = RUNNING
        self._apply_animations()

    def tick(self) -> None:
        """One pass of the application's loop (simulation running or not)."""
        for obj in self.objects.values():
            if obj.init_in is not None:
                obj.init_in -= 1
                if obj.init_in <= 0:
                    obj.init_in = None
                    obj.script_initialized = obj.script_enabled

    def _apply_animations(self) -> None:
        for handle, path in self.animations.items():
            if handle in self.objects:
                self.set_position(handle, list(path(self.time)), -1)

    def _finish_stop(self) -> None:
        self.positions_at_stop = {h: self.world_position(h) for h in self.objects}
        for handle, position in self._positions_at_start.items():
            if handle in self.objects:
                self.objects[handle].position = position
        self.state = STOPPED
        self.stop_requested = False
        self.step_count = 0

    # -- the sim.* functions -----------------------------------------------------------------

    def functions(self) -> dict[str, Callable[..., Any]]:
        """The ``sim`` functions this scene implements, by their CoppeliaSim names."""
        functions: dict[str, Callable[..., Any]] = {
            "getSimulationTime": lambda: self.time if self.running else 0.0,
            "getSimulationTimeStep": lambda: self.dt,
            "getSimulationState": lambda: self.state,
            "startSimulation": self.start_simulation,
            "stopSimulation": self.stop_simulation,
            "getInt32Param": self.get_int32_param,
            "getFloatParam": self.get_float_param,
            "setFloatParam": self.set_float_param,
            "createPrimitiveShape": self.create_primitive_shape,
            "createDummy": self.create_dummy,
            "initScript": self.init_script,
            "callScriptFunction": self.call_script_function,
            "removeObjects": self.remove_objects,
            "getObject": self.get_object,
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
            "setFloatSignal": self.set_float_signal,
            "getFloatSignal": lambda name: self.signals.get(name),
            "clearFloatSignal": self.clear_float_signal,
        }
        if self.release.script_objects:
            functions["createScript"] = self.create_script
        else:
            functions["addScript"] = self.add_script
            functions["setScriptStringParam"] = self.set_script_string_param
            functions["associateScriptWithObject"] = self.associate_script
            functions["removeScript"] = self.remove_script
        if self.release.properties:
            functions["setFloatProperty"] = self.set_float_property
            functions["getFloatProperty"] = self.get_float_property
            functions["setBoolProperty"] = self.set_bool_property
            functions["getBoolProperty"] = self.get_bool_property
        if not self.scripts:
            for name in (
                "createScript",
                "addScript",
                "initScript",
                "callScriptFunction",
                "removeScript",
            ):
                functions.pop(name, None)
        return functions

    def constants(self) -> dict[str, int]:
        """The ``sim`` constants this release lists."""
        constants = dict(SIM_CONSTANTS)
        if not self.release.script_objects:
            constants.update(SIM_CONSTANTS_46)
        return constants

    def start_simulation(self) -> int:
        if self.running:
            return 0
        self.state = FIRST_AFTER_STOP
        self.step_count = 0
        self._positions_at_start = {h: o.position for h, o in self.objects.items()}
        self._apply_animations()
        return 1

    def stop_simulation(self, wait: bool = False) -> None:
        # CoppeliaSim stops over its next passes, not within the call.
        if self.running:
            self.stop_requested = True

    def get_int32_param(self, param: int) -> int:
        if param != _C["intparam_program_version"]:
            raise CallRefused(f"unsupported int32 parameter {param}")
        return self.release.number

    def get_float_param(self, param: int) -> float:
        if param != _C["floatparam_simulation_time_step"]:
            raise CallRefused(f"unsupported float parameter {param}")
        return self.dt

    def set_float_param(self, param: int, value: float) -> int:
        if param != _C["floatparam_simulation_time_step"]:
            raise CallRefused(f"unsupported float parameter {param}")
        dt = _number(value, "value")
        if self.running:
            return 0  # as CoppeliaSim: no error, nothing changed
        self.dt = min(max(dt, MIN_DT), MAX_DT)
        return 1

    def set_float_property(self, target: int, name: str, value: float) -> None:
        self._scene_target(target)
        number = _number(value, "value")
        if name == "timeStep":
            if self.running:
                raise CallRefused("property 'timeStep' cannot be written while running")
            self.dt = min(max(number, MIN_DT), MAX_DT)
        elif isinstance(name, str) and name.startswith("signal.") and len(name) > 7:
            self.properties[name] = number
        else:
            raise CallRefused(f"unknown property {name!r}")

    def get_float_property(self, target: int, name: str, options: object = None) -> Any:
        self._scene_target(target)
        if name == "timeStep":
            return self.dt
        if name in self.properties:
            return self.properties[name]
        if isinstance(options, dict) and options.get("noError"):
            return None
        raise CallRefused(f"unknown property {name!r}")

    def set_bool_property(self, handle: int, name: str, value: bool) -> None:
        shape = self._get(handle)
        if shape.kind != "shape" or name not in ("dynamic", "respondable"):
            raise CallRefused(f"unknown property {name!r} of object {handle}")
        if not isinstance(value, bool):
            raise CallRefused(f"property {name!r}: expected a bool, got {value!r}")
        # The same flags the older sim.setObjectInt32Param sets.
        if name == "dynamic":
            shape.int_params[_C["shapeintparam_static"]] = int(not value)
        else:
            shape.int_params[_C["shapeintparam_respondable"]] = int(value)

    def get_bool_property(self, handle: int, name: str) -> bool:
        shape = self._get(handle)
        if shape.kind != "shape" or name not in ("dynamic", "respondable"):
            raise CallRefused(f"unknown property {name!r} of object {handle}")
        if name == "dynamic":
            return not shape.int_params.get(_C["shapeintparam_static"], 0)
        return bool(shape.int_params.get(_C["shapeintparam_respondable"], 0))

    def set_float_signal(self, name: str, value: float) -> None:
        if not isinstance(name, str) or not name:
            raise CallRefused(f"invalid signal name {name!r}")
        self.signals[name] = _number(value, "value")

    def clear_float_signal(self, name: str) -> None:
        self.signals.pop(name, None)

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

    def add_script(self, script_type: int) -> int:
        """4.6: a script attached to no object yet (not a scene object)."""
        if script_type != SIM_CONSTANTS_46["scripttype_customizationscript"]:
            raise CallRefused(f"unsupported script type {script_type!r}")
        return self._add_object(
            "script", "Script", script_type=script_type, script_lang="lua", scene_object=False
        )

    def set_script_string_param(self, handle: int, param: int, text: str) -> None:
        script = self._get_script(handle)
        if param != SIM_CONSTANTS_46["scriptstringparam_text"] or not isinstance(text, str):
            raise CallRefused(f"unsupported script string parameter {param!r}")
        script.script_text = text

    def associate_script(self, handle: int, object_handle: int) -> None:
        script = self._get_script(handle)
        self._get(object_handle)
        script.parent = object_handle

    def remove_script(self, handle: int) -> None:
        self._get_script(handle)
        del self.objects[handle]

    def init_script(self, handle: int) -> None:
        script = self._get_script(handle)
        if self.init_delay_passes:
            script.init_in = self.init_delay_passes  # the development line after 4.10
            return
        script.script_initialized = script.script_enabled

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
        # Like CoppeliaSim, the children of a removed object stay, now attached to the world;
        # the 4.6 scripts associated with it go with it.
        for handle in removed:
            for child in self.children(handle):
                if child not in removed:
                    self._reparent(child, -1, keep_in_place=True)
        attached = [
            h for h, o in self.objects.items() if not o.scene_object and o.parent in removed
        ]
        for handle in [*removed, *attached]:
            del self.objects[handle]
            self.animations.pop(handle, None)

    def get_object(self, path: str, options: object = None) -> int:
        """An object by absolute alias path, '/alias/childAlias/...'."""
        if not isinstance(path, str) or not path.startswith("/") or path == "/":
            raise CallRefused(f"invalid object path {path!r}")
        parent = -1
        for alias in path[1:].split("/"):
            matches = [
                h
                for h, o in self.objects.items()
                if o.scene_object and o.parent == parent and o.alias == alias
            ]
            if not matches:
                if isinstance(options, dict) and options.get("noError"):
                    return -1
                raise CallRefused("object does not exist.")
            parent = matches[0]
        return parent

    def objects_in_tree(self, base: int, object_type: int = -2, options: int = 0) -> list[int]:
        if base == _C["handle_world"] or base == _C["handle_scene"]:  # the scene: every object
            found = [h for h, o in self.objects.items() if o.scene_object]
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
        """What ``membraneSetPositions`` in ``batch_script.lua`` does."""
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

    def _get(self, handle: object, *, scripts: bool = False) -> FakeObject:
        obj = self.objects.get(handle) if isinstance(handle, int) else None
        if obj is None or not (obj.scene_object or scripts):
            raise CallRefused(f"object does not exist: {handle!r}")
        return obj

    def _get_script(self, handle: object) -> FakeObject:
        obj = self._get(handle, scripts=True)
        if obj.kind != "script":
            raise CallRefused(f"object {handle} is not a script")
        return obj

    def _scene_target(self, target: object) -> None:
        if target != _C["handle_scene"]:
            raise CallRefused(f"the stand-in has properties of the scene only, not of {target!r}")

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
