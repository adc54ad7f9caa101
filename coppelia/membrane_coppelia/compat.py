"""The calls each CoppeliaSim version (4.6 to 4.10) has for what the adapter does.

Checked against CoppeliaSim's own sources (docs/COPPELIA.md, "Versions", says where):

- script objects: ``sim.createScript(sim.scripttype_customization, text, 0, 'lua')`` from 4.7
  (a scene object: aliased, parented, removed with ``sim.removeObjects``); 4.6 has
  ``sim.addScript(sim.scripttype_customizationscript)``, ``sim.setScriptStringParam(h,
  sim.scriptstringparam_text, text)``, ``sim.associateScriptWithObject(h, object)`` and
  ``sim.removeScript(h)``.
- the time step: ``sim.setFloatProperty(sim.handle_scene, 'timeStep', dt)`` from 4.8;
  ``sim.setFloatParam(sim.floatparam_simulation_time_step, dt)`` before (deprecated from 4.8,
  present through 4.10), which returns 0 without an error while the simulation runs and clamps
  dt to [1e-4, 10]: the step is read back, and one that did not take is an error.
- shape flags: ``sim.setBoolProperty(h, 'dynamic' | 'respondable', ...)`` from 4.8;
  ``sim.setObjectInt32Param(h, sim.shapeintparam_static | _respondable, ...)`` before.
- float signals: ``sim.setFloatProperty(sim.handle_scene, 'signal.NAME', v)`` from 4.8 (a
  signal is a scene property); ``sim.setFloatSignal(NAME, v)`` before.

Which call to use is decided by what the connected ``sim`` object offers (the add-on lists every
function it has), so a build with a call back-ported or removed is served correctly; the version
number is read for messages.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from membrane_coppelia.link import SimulatorError

__all__ = [
    "MAX_TIME_STEP",
    "MIN_TIME_STEP",
    "SimCalls",
    "SimVersion",
    "TimeStepRefused",
    "read_version",
]

log = logging.getLogger(__name__)

MIN_TIME_STEP = 1e-4  # CoppeliaSim clamps the simulation time step to this range
MAX_TIME_STEP = 10.0
HANDLE_SCENE = -12  # sim.handle_scene, should a build not list it


class TimeStepRefused(SimulatorError):
    """CoppeliaSim kept another time step than the one asked for."""


@dataclass(frozen=True)
class SimVersion:
    """CoppeliaSim's version as ``sim.intparam_program_version`` gives it (4.9.2 is 40902)."""

    number: int

    @property
    def major_minor(self) -> tuple[int, int]:
        return (self.number // 10000, self.number // 100 % 100)

    def __str__(self) -> str:
        return f"{self.number // 10000}.{self.number // 100 % 100}.{self.number % 100}"


def read_version(sim: Any) -> SimVersion | None:
    """The connected CoppeliaSim's version, or None if it does not say (an error reply)."""
    try:
        return SimVersion(int(sim.getInt32Param(sim.intparam_program_version)))
    except AttributeError:
        return None
    except Exception as exc:
        if type(exc) is not Exception:  # the remote client's error replies are bare Exception
            raise
        return None


class SimCalls:
    """The call each operation takes on the connected CoppeliaSim.

    Methods make remote calls and let the remote client's exceptions through: callers wrap them
    (``translate_remote_errors``) with what they were doing.
    """

    def __init__(self, sim: Any, version: SimVersion | None = None) -> None:
        self.sim = sim
        self.version = version
        self.properties = hasattr(sim, "setFloatProperty") and hasattr(sim, "setBoolProperty")
        if hasattr(sim, "createScript"):
            self.scripts: str | None = "createScript"
        elif hasattr(sim, "addScript"):
            self.scripts = "addScript"
        else:
            self.scripts = None

    @property
    def name(self) -> str:
        """'CoppeliaSim 4.9.2' (or 'CoppeliaSim of unknown version'), for messages."""
        return f"CoppeliaSim {self.version}" if self.version else "CoppeliaSim of unknown version"

    @property
    def scene(self) -> int:
        return int(getattr(self.sim, "handle_scene", HANDLE_SCENE))

    # -- shapes ------------------------------------------------------------------------------

    def set_shape_flags(self, handle: int, static: bool, respondable: bool) -> None:
        """Make a shape static (not moved by physics) and respondable (collides), or not."""
        sim = self.sim
        if self.properties:
            sim.setBoolProperty(handle, "dynamic", not static)
            sim.setBoolProperty(handle, "respondable", respondable)
            return
        sim.setObjectInt32Param(handle, sim.shapeintparam_static, int(static))
        sim.setObjectInt32Param(handle, sim.shapeintparam_respondable, int(respondable))

    # -- the time step -----------------------------------------------------------------------

    def set_time_step(self, dt: float) -> None:
        """Set the simulation time step (simulation stopped), and check that it took.

        Raises:
            TimeStepRefused: ``dt`` is outside what CoppeliaSim accepts, or it kept another.
        """
        if not MIN_TIME_STEP <= dt <= MAX_TIME_STEP:
            raise TimeStepRefused(
                f"CoppeliaSim's time step must be in [{MIN_TIME_STEP:g}, {MAX_TIME_STEP:g}] s "
                f"(it clamps other values); the scene's dt is {dt:g} s"
            )
        sim = self.sim
        if self.properties:
            sim.setFloatProperty(self.scene, "timeStep", dt)
            how = "sim.setFloatProperty(sim.handle_scene, 'timeStep')"
        else:
            result = sim.setFloatParam(sim.floatparam_simulation_time_step, dt)
            how = f"sim.setFloatParam(sim.floatparam_simulation_time_step) returned {result!r}"
        actual = float(sim.getSimulationTimeStep())
        if abs(actual - dt) > 1e-9 * dt:
            raise TimeStepRefused(
                f"{self.name} kept its time step at {actual:g} s instead of the scene's "
                f"{dt:g} s ({how}); is the simulation stopped?"
            )

    # -- the batch script --------------------------------------------------------------------

    @property
    def script_objects(self) -> bool:
        """Whether scripts are scene objects (4.7+: aliased, parented, removed as objects)."""
        return self.scripts == "createScript"

    def install_script(self, text: str, parent: int, alias: str) -> int:
        """Install ``text`` as a customization script under ``parent``; returns its handle.

        The caller still initialises it (``sim.initScript``) and checks that it answers.
        """
        sim = self.sim
        if self.scripts == "createScript":
            handle = int(sim.createScript(sim.scripttype_customization, text, 0, "lua"))
            sim.setObjectAlias(handle, alias)
            sim.setObjectParent(handle, parent, True)
            return handle
        if self.scripts == "addScript":
            handle = int(sim.addScript(sim.scripttype_customizationscript))
            sim.setScriptStringParam(handle, sim.scriptstringparam_text, text)
            sim.associateScriptWithObject(handle, parent)
            return handle
        raise SimulatorError(f"{self.name} has neither sim.createScript nor sim.addScript")

    def remove_script(self, handle: int) -> None:
        """Remove a script :meth:`install_script` made."""
        if self.script_objects:
            self.sim.removeObjects([handle])
        else:
            self.sim.removeScript(handle)

    # -- signals -----------------------------------------------------------------------------

    @property
    def signal_call(self) -> str:
        """How :meth:`write_float_signal` writes, for messages and docs."""
        if self.properties:
            return "sim.setFloatProperty(sim.handle_scene, 'signal.NAME', value)"
        return "sim.setFloatSignal('NAME', value)"

    def write_float_signal(self, name: str, value: float) -> None:
        """Write a float signal a controller (or a haptic bridge) in the scene can read."""
        if self.properties:
            self.sim.setFloatProperty(self.scene, f"signal.{name}", float(value))
        else:
            self.sim.setFloatSignal(name, float(value))
