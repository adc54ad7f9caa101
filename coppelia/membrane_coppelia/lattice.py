"""The served lattice as spheres in a CoppeliaSim scene: built, moved every step, removed.

The lattice takes a ``sim`` object from the real ``coppeliasim-zmqremoteapi-client`` package
(the ``coppelia`` extra) and a membrane :class:`~membrane_client.Client`. It builds the lattice
the server describes (one spheroid per lattice point, under one parent dummy, so that the
lattice is placed and removed as a unit) and moves every sphere to a frame; what runs it step by
step is a film (:mod:`membrane_coppelia.film`) or a probe (:mod:`membrane_coppelia.probe`), in
the stepped simulation it holds (:mod:`membrane_coppelia.stepping`).

Two ways to move the spheres:

- ``batched``: one remote call per step. A small Lua function (``batch_script.lua``) is
  installed in the scene as a customization script (``sim.createScript`` from 4.7,
  ``sim.addScript`` on 4.6: :mod:`membrane_coppelia.compat`) and called with
  ``sim.callScriptFunction`` with every handle and position at once.
- ``per-sphere``: one ``sim.setObjectPosition`` per sphere per step (the fallback).

Positions are given relative to the parent dummy, which is created at the world origin: as
placed, sphere positions equal the served world positions; move the dummy to move the lattice.

After a timeout, or an interrupt in the middle of a request, the lattice makes no further call
on its connection; given ``reconnect``, it stops the simulation (and removes the lattice) from a
fresh one, so that an interrupted run never leaves CoppeliaSim held in stepping mode.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np

from membrane_client.client import Client
from membrane_client.frame import SceneInfo
from membrane_coppelia.batch_script import BATCH_FUNCTION, BATCH_SCRIPT
from membrane_coppelia.compat import SimCalls, read_version
from membrane_coppelia.interrupt import Interrupted
from membrane_coppelia.link import (
    CallGuard,
    SimulatorConnectionLost,
    SimulatorError,
    SimulatorLink,
)
from membrane_coppelia.stepping import SteppedSimulation

__all__ = ["BATCHED", "PER_SPHERE", "LatticeStyle", "SphereLattice"]

log = logging.getLogger(__name__)

# How the spheres move.
BATCHED = "batched"
PER_SPHERE = "per-sphere"
# From the development line after 4.10, sim.initScript may return before the script runs: the
# first call to its function is retried this long before the batched path is given up.
SCRIPT_READY_S = 1.0
SCRIPT_RETRY_S = 0.05


@dataclass(frozen=True)
class LatticeStyle:
    """How the spheres look and behave in the scene.

    Attributes:
        sphere_size: diameter of each spheroid, in world units (the study used 0.05).
        color: RGB in [0, 1] (ambient/diffuse component).
        static: static shapes (not moved by the physics engine), as in the study.
        respondable: shapes that collide with dynamic objects, as in the study.
        name: alias of the parent dummy; spheres are called ``node<i>``.
    """

    sphere_size: float = 0.05
    color: tuple[float, float, float] = (0.85, 0.35, 0.30)
    static: bool = True
    respondable: bool = True
    name: str = "membraneLattice"

    def __post_init__(self) -> None:
        if not self.sphere_size > 0:
            raise ValueError(f"sphere_size must be > 0, got {self.sphere_size}")
        if len(self.color) != 3 or not all(0.0 <= c <= 1.0 for c in self.color):
            raise ValueError(f"color must be 3 values in [0, 1], got {self.color}")
        if not self.name.replace("_", "").isalnum():
            raise ValueError(f"name must be letters, digits and '_', got {self.name!r}")


class SphereLattice:
    """The served lattice as spheres in a CoppeliaSim scene.

    Args:
        sim: the ``sim`` object of a ``RemoteAPIClient`` (timeouts applied, see
            :func:`~membrane_coppelia.link.connect_simulator`).
        client: a membrane client connected to the server (its ``scene`` selects the scene).
        style: size, colour and dynamics flags of the spheres.
        batched: move the lattice with one remote call per step when the simulator allows it.
        keep: leave the lattice in the scene when the context exits (or on :meth:`close`).
        address: CoppeliaSim's endpoint, for messages.
        timeout: the simulator socket's timeout in seconds, for messages.
        reconnect: opens a fresh connection to the same CoppeliaSim; used to stop the
            simulation (and remove the lattice) when this one became unusable.

    Use as a context manager: on exit the simulation is stopped (if this object started it) and
    the lattice removed, unless ``keep`` was set.
    """

    def __init__(
        self,
        sim: Any,
        client: Client,
        *,
        style: LatticeStyle | None = None,
        batched: bool = True,
        keep: bool = False,
        address: str = "CoppeliaSim",
        timeout: float | None = None,
        reconnect: Callable[[], SimulatorLink] | None = None,
    ) -> None:
        self.sim = sim
        self.client = client
        self.style = style or LatticeStyle()
        self.want_batched = batched
        self.keep = keep
        self.guard = CallGuard(address, timeout)
        self.simulation = SteppedSimulation(sim, self.guard, reconnect)
        self.info: SceneInfo | None = None
        self.calls: SimCalls | None = None
        self.parent: int | None = None
        self.handles: list[int] = []
        self.script: int | None = None
        self.path = PER_SPHERE

    @property
    def address(self) -> str:
        """CoppeliaSim's endpoint, for messages."""
        return self.guard.address

    @property
    def dead(self) -> bool:
        """Whether the connection became unusable (a timeout, an interrupted request)."""
        return self.guard.dead

    def calling(self, doing: str) -> AbstractContextManager[None]:
        """Make remote calls on this lattice's connection (:meth:`CallGuard.calling
        <membrane_coppelia.link.CallGuard.calling>`)."""
        return self.guard.calling(doing)

    def on_recover(self, action: Callable[[Any], None]) -> None:
        """Also run ``action(sim)`` when cleaning up over a fresh connection (after the stop;
        best effort: a failure is logged)."""
        self.simulation.on_recover(action)

    def scene_info(self) -> SceneInfo:
        """The scene the lattice was built for."""
        if self.info is None:
            raise RuntimeError("build() first")
        return self.info

    # -- building and removing ---------------------------------------------------------------

    def build(self, info: SceneInfo | None = None) -> None:
        """Create the parent dummy and one spheroid per lattice point, at rest positions.

        Args:
            info: the scene's description (default: ``describe`` the client's scene).
        """
        if self.parent is not None:
            raise RuntimeError("the lattice is already built: remove() it first")
        info = info or self.client.describe()
        self.info = info
        sim, style = self.sim, self.style
        with self.calling("reading CoppeliaSim's version"):
            self.calls = calls = SimCalls(sim, read_version(sim))
        log.info("connected to %s at %s", calls.name, self.address)
        rest = info.rest_positions()
        log.info("building %d spheres for scene %s in %s", info.n_points, info.name, self.address)
        with self.calling("building the lattice"):
            self.parent = sim.createDummy(style.sphere_size)
            sim.setObjectAlias(self.parent, style.name)
            sim.setObjectPosition(self.parent, [0.0, 0.0, 0.0], sim.handle_world)
            size = [style.sphere_size] * 3
            for index, position in enumerate(rest.tolist()):
                handle = sim.createPrimitiveShape(sim.primitiveshape_spheroid, size, 0)
                self.handles.append(handle)
                self._dress(calls, handle, index, position)
        self.path = PER_SPHERE
        if self.want_batched:
            self._install_batch_script(calls)
        log.info("lattice built: %d spheres, moved %s", len(self.handles), self.path)

    def _dress(self, calls: SimCalls, handle: int, index: int, position: list[float]) -> None:
        sim, style = self.sim, self.style
        sim.setObjectAlias(handle, f"node{index}")
        calls.set_shape_flags(handle, style.static, style.respondable)
        sim.setShapeColor(handle, None, sim.colorcomponent_ambient_diffuse, list(style.color))
        sim.setObjectParent(handle, self.parent, True)
        sim.setObjectPosition(handle, position, self.parent)

    def _install_batch_script(self, calls: SimCalls) -> None:
        """Install the Lua mover and check it answers; otherwise stay on the per-sphere path."""
        if calls.scripts is None:
            log.warning(
                "%s has neither sim.createScript (4.7+) nor sim.addScript (4.6): moving sphere "
                "by sphere, one call per sphere per step",
                calls.name,
            )
            return
        try:
            with self.calling("installing the batch script"):
                alias = f"{self.style.name}Mover"
                self.script = calls.install_script(BATCH_SCRIPT, self._parent(), alias)
                self.sim.initScript(self.script)
            moved = self._first_batch_call()
            if moved != 0:
                raise SimulatorError(f"the batch script answered {moved!r} to an empty call")
        except SimulatorConnectionLost:
            raise
        except (SimulatorError, AttributeError) as exc:  # AttributeError: no such sim function
            log.warning(
                "batched moves unavailable on %s, moving sphere by sphere: %s", calls.name, exc
            )
            self._remove_script(calls)
            return
        self.path = BATCHED

    def _first_batch_call(self) -> Any:
        # initScript returns before the script has run in the development line after 4.10: a
        # function it defines may not exist yet for a moment.
        deadline = time.monotonic() + SCRIPT_READY_S
        while True:
            try:
                with self.calling("calling the batch script"):
                    return self.sim.callScriptFunction(
                        BATCH_FUNCTION, self.script, [], [], self.parent
                    )
            except SimulatorConnectionLost:
                raise
            except SimulatorError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(SCRIPT_RETRY_S)

    def _remove_script(self, calls: SimCalls) -> None:
        if self.script is None:
            return
        script, self.script = self.script, None
        try:
            with self.calling("removing the batch script"):
                calls.remove_script(script)
        except SimulatorConnectionLost:
            raise
        except SimulatorError as exc:
            log.warning("could not remove the batch script %d: %s", script, exc)

    def remove(self) -> None:
        """Remove every object this lattice created (spheres, script, parent dummy)."""
        if not self.dead:
            with self.calling("removing the lattice"):
                self._remove_with(self.sim)
        self.handles, self.script, self.parent = [], None, None

    def _remove_with(self, sim: Any) -> None:
        created = [*self.handles]
        if self.script is not None and self.calls is not None and not self.calls.script_objects:
            sim.removeScript(self.script)  # 4.6: a script is not a scene object
        elif self.script is not None:
            created.append(self.script)
        if self.parent is not None:
            created.append(self.parent)
        if created:
            sim.removeObjects(created)

    # -- moving ------------------------------------------------------------------------------

    def move(self, positions: np.ndarray) -> None:
        """Move every sphere to ``positions`` ((n, 3), relative to the parent dummy)."""
        if positions.shape != (len(self.handles), 3):
            raise ValueError(f"expected ({len(self.handles)}, 3) positions, got {positions.shape}")
        if self.path == BATCHED:
            flat = positions.reshape(-1).tolist()  # plain floats: the client's CBOR needs them
            moved = self.sim.callScriptFunction(
                BATCH_FUNCTION, self.script, self.handles, flat, self.parent
            )
            if moved != len(self.handles):
                raise SimulatorError(f"the batch script moved {moved!r} of {len(self.handles)}")
            return
        set_position, parent = self.sim.setObjectPosition, self.parent
        for handle, xyz in zip(self.handles, positions.tolist(), strict=True):
            set_position(handle, xyz, parent)

    # -- the stepped simulation --------------------------------------------------------------

    def start(self) -> float:
        """Set the scene's time step, enter stepping mode and start; returns the simulator's dt.

        Raises:
            TimeStepRefused: CoppeliaSim would not take the scene's dt.
        """
        return self.simulation.start(self.scene_info().dt, self.calls)

    def step(self) -> None:
        """One simulation step (``sim.step()``: returns when CoppeliaSim has taken it)."""
        self.simulation.step()

    def stop(self) -> None:
        """Stop the simulation if this lattice started it (from a fresh connection if this
        one is unusable and ``reconnect`` was given)."""
        self.simulation.stop()

    # -- cleaning up -------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the simulation and, unless ``keep``, remove the lattice.

        With an unusable connection both happen over a fresh one (``reconnect``), or not at all.
        """
        simulation = self.simulation
        if not self.dead:
            try:
                try:
                    simulation.stop()
                finally:
                    if not self.keep and not self.dead:
                        self.remove()
                return
            except SimulatorConnectionLost:
                if simulation.reconnect is None:
                    raise
        if simulation.reconnect is not None:
            leftover = not self.keep and self.parent is not None
            simulation.recover(self._remove_over if leftover else None)
        elif simulation.running:
            raise simulation.lost()

    def _remove_over(self, sim: Any) -> None:
        self._remove_with(sim)
        self.handles, self.script, self.parent = [], None, None

    def __enter__(self) -> SphereLattice:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc is None:
            self.close()
            return
        try:  # cleaning up must not hide the error that ended the run
            self.close()
        except SimulatorError as cleanup_error:
            # A simulator that stopped answering cannot be cleaned up either: no second line.
            same_cause = isinstance(exc, SimulatorConnectionLost) and isinstance(
                cleanup_error, SimulatorConnectionLost
            )
            log.log(
                logging.INFO if same_cause else logging.WARNING,
                "cleanup after an error failed: %s",
                cleanup_error,
            )
        if isinstance(exc, Interrupted) and self.simulation.started:
            exc.simulator_released = not self.simulation.running

    def _parent(self) -> int:
        if self.parent is None:
            raise RuntimeError("build() first")
        return self.parent
