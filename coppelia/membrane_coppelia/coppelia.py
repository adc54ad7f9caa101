"""Drive a lattice of spheres in CoppeliaSim from a membrane server.

The adapter takes a ``sim`` object from the real ``coppeliasim-zmqremoteapi-client`` package
(the ``coppelia`` extra) and a membrane :class:`~membrane_client.Client`. It builds the lattice
the server describes (one spheroid per lattice point, under one parent dummy, so that the
lattice is placed and removed as a unit), then runs the simulation in stepping mode: at each
step it asks the server for the frame (a film's ``query`` at the simulation time here; a live
session's step in :mod:`membrane_coppelia.coppelia_probe`), moves every sphere, and calls
``sim.step()``.

Two ways to move the spheres:

- ``batched``: one remote call per step. A small Lua function (``coppelia_batch.lua``) is
  installed in the scene as a customization script (``sim.createScript`` from 4.7,
  ``sim.addScript`` on 4.6: :mod:`membrane_coppelia.coppelia_compat`) and called with
  ``sim.callScriptFunction`` with every handle and position at once.
- ``per-sphere``: one ``sim.setObjectPosition`` per sphere per step (the fallback).

Positions are given relative to the parent dummy, which is created at the world origin: as
placed, sphere positions equal the served world positions; move the dummy to move the lattice.

Connections and their timeouts are :mod:`membrane_coppelia.coppelia_link`'s. After a timeout,
or an interrupt in the middle of a request, this object makes no further call on its
connection; given ``reconnect``, it stops the simulation (and removes the lattice) from a fresh
one, so that an interrupted run never leaves CoppeliaSim held in stepping mode.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

import numpy as np

from membrane_client.client import DEFAULT_ADDRESS, Client
from membrane_client.errors import ServerError
from membrane_client.frame import SceneInfo
from membrane_client.protocol import ErrorCode
from membrane_coppelia.coppelia_compat import SimCalls, read_version
from membrane_coppelia.coppelia_interrupt import Interrupted, raise_if_interrupted
from membrane_coppelia.coppelia_link import (
    DEFAULT_REMOTE_TIMEOUT,
    DEFAULT_SIM_HOST,
    DEFAULT_SIM_PORT,
    SimulatorConnectionLost,
    SimulatorError,
    SimulatorLink,
    SimulatorTimeout,
    apply_timeouts,
    connect_simulator,
    one_line,
    stop_and_wait,
    translate_remote_errors,
)
from membrane_coppelia.coppelia_lua import BATCH_FUNCTION, BATCH_SCRIPT

__all__ = [
    "BATCHED",
    "DEFAULT_SIM_HOST",
    "DEFAULT_SIM_PORT",
    "PER_SPHERE",
    "LatticeStyle",
    "RunResult",
    "SimulatorConnectionLost",
    "SimulatorError",
    "SimulatorLink",
    "SimulatorTimeout",
    "SphereLattice",
    "StepTimings",
    "apply_timeouts",
    "connect_simulator",
    "drive_lattice",
]

log = logging.getLogger(__name__)

BATCHED = "batched"
PER_SPHERE = "per-sphere"
COMPLETED = "completed"
OUT_OF_DOMAIN = "out_of_domain"
MAX_STEPS = "max_steps"
# From the development line after 4.10, sim.initScript may return before the script runs: the
# first call to its function is retried this long before the batched path is given up.
SCRIPT_READY_S = 1.0
SCRIPT_RETRY_S = 0.05


# -- what a run reports ---------------------------------------------------------------------


@dataclass
class StepTimings:
    """Wall-clock seconds spent in each part of every step.

    ``read``: reading the simulator (the simulation time, or a probe's position); ``query``: the
    membrane server's answer (a film's ``query``, a live session's ``step``); ``move``: moving
    every sphere (one call when batched, one per sphere otherwise); ``step``: ``sim.step()``
    with its handshake; ``total``: the whole step.
    """

    read: list[float] = field(default_factory=list)
    query: list[float] = field(default_factory=list)
    move: list[float] = field(default_factory=list)
    step: list[float] = field(default_factory=list)
    total: list[float] = field(default_factory=list)

    def percentiles(self) -> dict[str, dict[str, float]]:
        """``{part: {"p50": s, "p99": s}}`` for the parts measured at least once."""
        parts = {
            "read": self.read,
            "query": self.query,
            "move": self.move,
            "step": self.step,
            "total": self.total,
        }
        return {
            name: {
                "p50": float(np.percentile(values, 50)),
                "p99": float(np.percentile(values, 99)),
            }
            for name, values in parts.items()
            if values
        }

    def summary(self) -> str:
        """One line: p50 / p99 in milliseconds of every part."""
        return "  ".join(
            f"{name} {p['p50'] * 1e3:.3f}/{p['p99'] * 1e3:.3f} ms"
            for name, p in self.percentiles().items()
        )


@dataclass
class RunResult:
    """What :meth:`SphereLattice.run` did.

    Attributes:
        scene: the scene's name.
        spheres: how many spheres the lattice has.
        steps: simulation steps taken.
        first_t, last_t: simulation times of the first and last frame shown (NaN if none).
        path: how spheres moved, ``"batched"`` or ``"per-sphere"``.
        reason: why the run ended: ``"completed"`` (end time reached), ``"max_steps"``, or
            ``"out_of_domain"`` (the server refused a time under the scene's ``error`` policy).
        message: one line for people about how the run ended.
        sim_dt: the simulator's time step during the run.
        timings: per-step wall-clock times.
        last_positions: (n, 3) positions sent at the last step (world coordinates as served).
    """

    scene: str
    spheres: int
    steps: int
    first_t: float
    last_t: float
    path: str
    reason: str
    message: str
    sim_dt: float
    timings: StepTimings
    last_positions: np.ndarray | None


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


# -- the adapter ----------------------------------------------------------------------------


class SphereLattice:
    """The served lattice as spheres in a CoppeliaSim scene.

    Args:
        sim: the ``sim`` object of a ``RemoteAPIClient`` (timeouts applied, see
            :func:`~membrane_coppelia.coppelia_link.connect_simulator`).
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
        self.address = address
        self.timeout = timeout
        self.reconnect = reconnect
        self.info: SceneInfo | None = None
        self.calls: SimCalls | None = None
        self.parent: int | None = None
        self.handles: list[int] = []
        self.script: int | None = None
        self.path = PER_SPHERE
        self._running = False
        self._started = False
        self._dead = False  # the connection's REQ socket may be stuck: never use it again
        self._recover_actions: list[Callable[[Any], None]] = []

    @property
    def dead(self) -> bool:
        """Whether the connection became unusable (a timeout, an interrupted request)."""
        return self._dead

    def on_recover(self, action: Callable[[Any], None]) -> None:
        """Also run ``action(sim)`` when cleaning up over a fresh connection (after the stop;
        best effort: a failure is logged)."""
        self._recover_actions.append(action)

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
        if not self._dead:
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

    # -- moving and stepping -----------------------------------------------------------------

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

    def start(self) -> float:
        """Set the scene's time step, enter stepping mode and start; returns the simulator's dt.

        Raises:
            TimeStepRefused: CoppeliaSim would not take the scene's dt.
        """
        sim, info = self.sim, self._info()
        with self.calling("starting the simulation"):
            if sim.getSimulationState() != sim.simulation_stopped:
                log.warning("the simulation was already running; stopping it first")
                stop_and_wait(sim)
            self._match_time_step(info.dt)
            # From here on cleaning up means stopping (which also resets our stepping level):
            # marked first, so that an interrupt inside either call still leads to a stop.
            self._running = self._started = True
            # The remote API add-on resets stepping whenever the simulation stops: set it anew.
            sim.setStepping(True)
            sim.startSimulation()
            sim_dt = float(sim.getSimulationTimeStep())
        return sim_dt

    def _match_time_step(self, dt: float) -> None:
        current = float(self.sim.getSimulationTimeStep())
        if abs(current - dt) <= 1e-12:
            return
        calls = self.calls or SimCalls(self.sim)
        calls.set_time_step(dt)
        # The user's simulator setting changes (and stays changed): say so, once.
        log.warning(
            "changed the simulator's time step from %g s to %g s (the scene's dt); "
            "it stays so after the run",
            current,
            dt,
        )

    def step(self) -> None:
        """One simulation step (``sim.step()``: returns when CoppeliaSim has taken it)."""
        with self.calling("stepping the simulation"):
            self.sim.step()

    def run(
        self,
        duration: float | None = None,
        max_steps: int | None = None,
        on_step: Callable[[int, float], None] | None = None,
    ) -> RunResult:
        """Run the simulation in stepping mode, showing the served film at every step.

        Args:
            duration: simulation time to run to, seconds (default: the scene's end,
                ``start_offset + duration``). Past the scene's end the scene's policy decides:
                under ``error`` the run ends cleanly at the first refused time.
            max_steps: stop after this many steps (default: no limit).
            on_step: called after every step with (steps done, simulation time shown).

        Returns:
            What happened, with per-step timings. The simulation is stopped on return.
        """
        if self.parent is None:
            self.build()
        info = self._info()
        end_t = info.start_offset + info.duration if duration is None else duration
        if not end_t >= 0:
            raise ValueError(f"duration must be >= 0 seconds, got {duration}")
        if max_steps is not None and max_steps < 0:
            raise ValueError(f"max_steps must be >= 0, got {max_steps}")
        try:
            sim_dt = self.start()
            return self._loop(info, end_t, max_steps, sim_dt, on_step)
        finally:
            if not self._dead:
                self.stop()

    def _loop(
        self,
        info: SceneInfo,
        end_t: float,
        max_steps: int | None,
        sim_dt: float,
        on_step: Callable[[int, float], None] | None,
    ) -> RunResult:
        sim, client = self.sim, self.client
        timings = StepTimings()
        steps, first_t, last_t = 0, float("nan"), float("nan")
        positions: np.ndarray | None = None
        reason, message = COMPLETED, ""
        slack = 1e-6 * sim_dt  # float noise of the simulator's clock, not a real overshoot
        while True:
            raise_if_interrupted()  # a signal whose exception a finalizer swallowed
            if max_steps is not None and steps >= max_steps:
                reason = MAX_STEPS
                break
            start = time.perf_counter()
            with self.calling("reading the simulation time"):
                t = float(sim.getSimulationTime())
            if t > end_t + slack:
                break
            t = min(t, end_t)
            clock = time.perf_counter()
            if t < info.start_offset and info.policy == "error":
                positions = info.rest_positions()  # before the response starts: at rest
            else:
                try:
                    positions = client.query(t).positions()
                except ServerError as exc:
                    if exc.code != ErrorCode.OUT_OF_DOMAIN:
                        raise
                    reason, message = OUT_OF_DOMAIN, f"stopped at t = {t:g} s: {exc.message}"
                    break
            queried = time.perf_counter()
            with self.calling("moving the spheres"):
                self.move(positions)
            moved = time.perf_counter()
            self.step()
            stepped = time.perf_counter()
            timings.read.append(clock - start)
            timings.query.append(queried - clock)
            timings.move.append(moved - queried)
            timings.step.append(stepped - moved)
            timings.total.append(stepped - start)
            first_t = t if steps == 0 else first_t
            last_t = t
            steps += 1
            if on_step is not None:
                on_step(steps, t)
        if not message:
            message = f"{steps} steps, t = {first_t:g} .. {last_t:g} s ({reason})"
        return RunResult(
            scene=info.name,
            spheres=len(self.handles),
            steps=steps,
            first_t=first_t,
            last_t=last_t,
            path=self.path,
            reason=reason,
            message=message,
            sim_dt=sim_dt,
            timings=timings,
            last_positions=positions,
        )

    # -- stopping and cleaning up ------------------------------------------------------------

    def stop(self) -> None:
        """Stop the simulation if this lattice started it (from a fresh connection if this
        one is unusable and ``reconnect`` was given)."""
        if not self._running:
            return
        if not self._dead:
            with self.calling("stopping the simulation"):
                stop_and_wait(self.sim)
        elif self.reconnect is not None:
            self._recover(remove=False)
        else:
            raise SimulatorError(
                f"the connection to {self.address} was lost: the simulation may still run"
            )
        self._running = False

    def close(self) -> None:
        """Stop the simulation and, unless ``keep``, remove the lattice.

        With an unusable connection both happen over a fresh one (``reconnect``), or not at all.
        """
        if not self._dead:
            try:
                try:
                    self.stop()
                finally:
                    if not self.keep and not self._dead:
                        self.remove()
                return
            except SimulatorConnectionLost:
                if self.reconnect is None:
                    raise
        if self.reconnect is not None:
            self._recover(remove=not self.keep)
        elif self._running:
            raise SimulatorError(
                f"the connection to {self.address} was lost: the simulation may still run"
            )

    def _recover(self, remove: bool) -> None:
        assert self.reconnect is not None
        if not self._running and not (remove and self.parent is not None):
            return
        log.info("cleaning up over a fresh connection to %s", self.address)
        link = self.reconnect()
        try:
            with translate_remote_errors(link.address, link.timeout, "cleaning up"):
                if self._running:
                    stop_and_wait(link.sim)
                    self._running = False
                for action in self._recover_actions:
                    try:
                        action(link.sim)
                    except Exception as exc:
                        if type(exc) is not Exception:  # not the remote client's error reply
                            raise
                        log.warning("cleanup over a fresh connection: %s", one_line(exc))
                if remove and self.parent is not None:
                    self._remove_with(link.sim)
                    self.handles, self.script, self.parent = [], None, None
        finally:
            link.close()

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
        if isinstance(exc, Interrupted) and self._started:
            exc.simulator_released = not self._running

    # -- helpers -----------------------------------------------------------------------------

    def _info(self) -> SceneInfo:
        if self.info is None:
            raise RuntimeError("build() first")
        return self.info

    def _parent(self) -> int:
        if self.parent is None:
            raise RuntimeError("build() first")
        return self.parent

    @contextmanager
    def calling(self, doing: str) -> Iterator[None]:
        """Make remote calls: their errors become SimulatorError; after a lost connection, or
        an interrupt in the middle of a call, no further call is made on it."""
        if self._dead:
            raise SimulatorConnectionLost(f"the connection to {self.address} was lost earlier")
        try:
            with translate_remote_errors(self.address, self.timeout, doing):
                yield
        except SimulatorConnectionLost:
            self._dead = True
            raise
        except BaseException as exc:
            if not isinstance(exc, Exception):  # an interrupt: the REQ socket may be stuck
                self._dead = True
            raise


def simulator_reconnect(
    host: str, port: int, timeout: float, remote_timeout: float
) -> Callable[[], SimulatorLink]:
    """A ``reconnect`` for :class:`SphereLattice`: a fresh connection to the same CoppeliaSim."""
    return lambda: connect_simulator(host, port, timeout, remote_timeout)


def drive_lattice(
    server: str = DEFAULT_ADDRESS,
    *,
    scene: str | None = None,
    sim_host: str = DEFAULT_SIM_HOST,
    sim_port: int = DEFAULT_SIM_PORT,
    duration: float | None = None,
    max_steps: int | None = None,
    batched: bool = True,
    keep: bool = False,
    style: LatticeStyle | None = None,
    sim_timeout: float = 5.0,
    server_timeout: float = 1.0,
    remote_timeout: float = DEFAULT_REMOTE_TIMEOUT,
    on_step: Callable[[int, float], None] | None = None,
) -> RunResult:
    """Connect to a membrane server and to CoppeliaSim, build the lattice, run, clean up.

    Arguments as in :class:`SphereLattice` and :meth:`SphereLattice.run`.

    Raises:
        SimulatorTimeout: CoppeliaSim did not answer within ``sim_timeout``.
        SimulatorError: CoppeliaSim refused a call.
        membrane_client.Timeout / ServerError: the membrane server did not answer, or refused.
        Interrupted: SIGINT or SIGTERM (under ``interrupt_on``); the simulation was stopped.
    """
    link = connect_simulator(sim_host, sim_port, sim_timeout, remote_timeout)
    try:
        with (
            Client(server, timeout=server_timeout, scene=scene) as client,
            SphereLattice(
                link.sim,
                client,
                style=style,
                batched=batched,
                keep=keep,
                address=link.address,
                timeout=sim_timeout,
                reconnect=simulator_reconnect(sim_host, sim_port, sim_timeout, remote_timeout),
            ) as lattice,
        ):
            try:
                lattice.build()
                return lattice.run(duration=duration, max_steps=max_steps, on_step=on_step)
            finally:
                link.broken = lattice.dead
    finally:
        link.close()
