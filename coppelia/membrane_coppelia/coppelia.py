"""Drive a lattice of spheres in CoppeliaSim from a membrane server.

The adapter takes a ``sim`` object from the real ``coppeliasim-zmqremoteapi-client`` package
(the ``coppelia`` extra) and a membrane :class:`~membrane_client.Client`. It builds the lattice
the server describes (one spheroid per lattice point, under one parent dummy, so that the
lattice is placed and removed as a unit), then runs the simulation in stepping mode: at each
step it queries the server at the simulation time, moves every sphere, and calls ``sim.step()``.

Two ways to move the spheres:

- ``batched``: one remote call per step. A small Lua function (``coppelia_batch.lua``) is
  installed in the scene as a customization script (``sim.createScript`` + ``sim.initScript``)
  and called with ``sim.callScriptFunction`` with every handle and position at once. Used when
  the simulator accepts it.
- ``per-sphere``: one ``sim.setObjectPosition`` per sphere per step (the fallback).

Positions are given relative to the parent dummy, which is created at the world origin: as
placed, sphere positions equal the served world positions; move the dummy to move the lattice.

The remote API client sets no receive timeout, so a dead CoppeliaSim would hang it forever;
:func:`connect_simulator` (or :func:`apply_timeouts`) sets ``RCVTIMEO``/``SNDTIMEO`` and
``LINGER`` 0 on its socket, and the adapter turns the resulting ``zmq.Again`` into
:class:`SimulatorTimeout`. After a timeout the connection is not used again.
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
import zmq

from membrane_client.client import DEFAULT_ADDRESS, Client
from membrane_client.errors import MembraneError, ServerError
from membrane_client.frame import SceneInfo
from membrane_client.protocol import ErrorCode
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

DEFAULT_SIM_HOST = "127.0.0.1"
DEFAULT_SIM_PORT = 23000  # the ZeroMQ remote API add-on's default port
BATCHED = "batched"
PER_SPHERE = "per-sphere"
COMPLETED = "completed"
OUT_OF_DOMAIN = "out_of_domain"
MAX_STEPS = "max_steps"
STOP_WAIT_S = 10.0  # how long a stop may take before we call it a failure


class SimulatorError(MembraneError):
    """CoppeliaSim refused a call, or the connection to it failed."""


class SimulatorConnectionLost(SimulatorError):
    """The connection to CoppeliaSim is unusable (its REQ socket is stuck): make no more calls."""


class SimulatorTimeout(SimulatorConnectionLost):
    """CoppeliaSim did not answer within the timeout."""


# -- the connection to CoppeliaSim ----------------------------------------------------------


def apply_timeouts(remote: Any, timeout: float) -> None:
    """Give a ``RemoteAPIClient``'s socket a receive/send timeout and LINGER 0.

    Without them a dead CoppeliaSim blocks the client forever, and the process hangs at exit
    on the unsent request.

    Args:
        remote: a ``coppeliasim_zmqremoteapi_client.RemoteAPIClient``.
        timeout: seconds to wait for each reply (> 0).
    """
    if not timeout > 0:
        raise ValueError(f"the simulator timeout must be > 0 seconds, got {timeout}")
    milliseconds = max(1, round(timeout * 1000))
    remote.socket.setsockopt(zmq.RCVTIMEO, milliseconds)
    remote.socket.setsockopt(zmq.SNDTIMEO, milliseconds)
    remote.socket.setsockopt(zmq.LINGER, 0)


@dataclass
class SimulatorLink:
    """A connection to CoppeliaSim's ZeroMQ remote API: the client and its ``sim`` object."""

    remote: Any
    sim: Any
    address: str
    timeout: float

    def close(self) -> None:
        """Close the socket at once (LINGER 0)."""
        self.remote.socket.close(linger=0)


def connect_simulator(
    host: str = DEFAULT_SIM_HOST, port: int = DEFAULT_SIM_PORT, timeout: float = 5.0
) -> SimulatorLink:
    """Connect to CoppeliaSim (or the stand-in) and fetch its ``sim`` object.

    Raises:
        SimulatorTimeout: nothing answered within ``timeout`` seconds.
        ModuleNotFoundError: the ``coppelia`` extra is not installed.
    """
    from coppeliasim_zmqremoteapi_client import RemoteAPIClient

    if not 0 < port < 65536:
        raise ValueError(f"the simulator port must be in 1..65535, got {port}")
    address = f"tcp://{host}:{port}"
    remote = RemoteAPIClient(host, port)
    apply_timeouts(remote, timeout)
    link = SimulatorLink(remote=remote, sim=None, address=address, timeout=timeout)
    try:
        with _translate_remote_errors(link.address, timeout, "fetching the sim API"):
            link.sim = remote.require("sim")
    except BaseException:
        link.close()
        raise
    return link


@contextmanager
def _translate_remote_errors(address: str, timeout: float | None, doing: str) -> Iterator[None]:
    """Turn what the remote API client raises into SimulatorError / SimulatorTimeout."""
    try:
        yield
    except zmq.Again:
        within = f" within {timeout:g} s" if timeout is not None else ""
        raise SimulatorTimeout(
            f"CoppeliaSim at {address} did not answer{within} while {doing} "
            "(is it running, with the ZeroMQ remote API add-on on that port?)"
        ) from None
    except zmq.ZMQError as exc:
        raise SimulatorConnectionLost(
            f"ZeroMQ error talking to CoppeliaSim at {address}: {exc}"
        ) from None
    except Exception as exc:
        if type(exc) is not Exception:  # the client raises bare Exception for an error reply
            raise
        raise SimulatorError(
            f"CoppeliaSim refused a call while {doing}: {_one_line(exc)}"
        ) from None


def _one_line(exc: BaseException) -> str:
    # The remote API server encodes newlines and tabs of Lua tracebacks as _=NL=_ and _=TB=_.
    text = str(exc).replace("_=NL=_", " ").replace("_=TB=_", " ")
    return " ".join(text.split()) or type(exc).__name__


# -- what a run reports ---------------------------------------------------------------------


@dataclass
class StepTimings:
    """Wall-clock seconds spent in each part of every step.

    ``query``: the membrane server's ``query``; ``move``: moving every sphere (one call when
    batched, one per sphere otherwise); ``step``: ``sim.step()`` with its handshake; ``total``:
    the whole step, reading the simulation time included.
    """

    query: list[float] = field(default_factory=list)
    move: list[float] = field(default_factory=list)
    step: list[float] = field(default_factory=list)
    total: list[float] = field(default_factory=list)

    def percentiles(self) -> dict[str, dict[str, float]]:
        """``{part: {"p50": s, "p99": s}}`` for the parts measured at least once."""
        parts = {"query": self.query, "move": self.move, "step": self.step, "total": self.total}
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
            :func:`apply_timeouts`).
        client: a membrane client connected to the server (its ``scene`` selects the scene).
        style: size, colour and dynamics flags of the spheres.
        batched: move the lattice with one remote call per step when the simulator allows it.
        keep: leave the lattice in the scene when the context exits (or on :meth:`close`).
        address: CoppeliaSim's endpoint, for messages.
        timeout: the simulator socket's timeout in seconds, for messages.

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
    ) -> None:
        self.sim = sim
        self.client = client
        self.style = style or LatticeStyle()
        self.want_batched = batched
        self.keep = keep
        self.address = address
        self.timeout = timeout
        self.info: SceneInfo | None = None
        self.parent: int | None = None
        self.handles: list[int] = []
        self.script: int | None = None
        self.path = PER_SPHERE
        self._running = False
        self._dead = False  # after a timeout the REQ socket must not be used again

    # -- building and removing ---------------------------------------------------------------

    def build(self) -> None:
        """Create the parent dummy and one spheroid per lattice point, at rest positions."""
        if self.parent is not None:
            raise RuntimeError("the lattice is already built: remove() it first")
        info = self.client.describe()
        self.info = info
        sim, style = self.sim, self.style
        rest = info.rest_positions()
        log.info("building %d spheres for scene %s in %s", info.n_points, info.name, self.address)
        with self._remote("building the lattice"):
            self.parent = sim.createDummy(style.sphere_size)
            sim.setObjectAlias(self.parent, style.name)
            sim.setObjectPosition(self.parent, [0.0, 0.0, 0.0], sim.handle_world)
            size = [style.sphere_size] * 3
            for index, position in enumerate(rest.tolist()):
                handle = sim.createPrimitiveShape(sim.primitiveshape_spheroid, size, 0)
                self.handles.append(handle)
                self._dress(handle, index, position)
        self.path = PER_SPHERE
        if self.want_batched:
            self._install_batch_script()
        log.info("lattice built: %d spheres, moved %s", len(self.handles), self.path)

    def _dress(self, handle: int, index: int, position: list[float]) -> None:
        sim, style = self.sim, self.style
        sim.setObjectAlias(handle, f"node{index}")
        sim.setObjectInt32Param(handle, sim.shapeintparam_static, int(style.static))
        sim.setObjectInt32Param(handle, sim.shapeintparam_respondable, int(style.respondable))
        sim.setShapeColor(handle, None, sim.colorcomponent_ambient_diffuse, list(style.color))
        sim.setObjectParent(handle, self.parent, True)
        sim.setObjectPosition(handle, position, self.parent)

    def _install_batch_script(self) -> None:
        """Install the Lua mover and check it answers; otherwise stay on the per-sphere path."""
        sim = self.sim
        try:
            with self._remote("installing the batch script"):
                self.script = sim.createScript(sim.scripttype_customization, BATCH_SCRIPT, 0, "lua")
                sim.setObjectAlias(self.script, f"{self.style.name}Mover")
                sim.setObjectParent(self.script, self.parent, True)
                sim.initScript(self.script)
                moved = sim.callScriptFunction(BATCH_FUNCTION, self.script, [], [], self.parent)
            if moved != 0:
                raise SimulatorError(f"the batch script answered {moved!r} to an empty call")
        except SimulatorConnectionLost:
            raise
        except (SimulatorError, AttributeError) as exc:  # AttributeError: no such sim function
            log.warning("batched moves unavailable, moving sphere by sphere: %s", exc)
            self._remove_script()
            return
        self.path = BATCHED

    def _remove_script(self) -> None:
        if self.script is None:
            return
        script, self.script = self.script, None
        try:
            with self._remote("removing the batch script"):
                self.sim.removeObjects([script])
        except SimulatorConnectionLost:
            raise
        except SimulatorError as exc:
            log.warning("could not remove the batch script %d: %s", script, exc)

    def remove(self) -> None:
        """Remove every object this lattice created (spheres, script, parent dummy)."""
        created = [*self.handles]
        if self.script is not None:
            created.append(self.script)
        if self.parent is not None:
            created.append(self.parent)
        if created and not self._dead:
            with self._remote("removing the lattice"):
                self.sim.removeObjects(created)
        self.handles, self.script, self.parent = [], None, None

    # -- moving and running -----------------------------------------------------------------

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

    def run(
        self,
        duration: float | None = None,
        max_steps: int | None = None,
        on_step: Callable[[int, float], None] | None = None,
    ) -> RunResult:
        """Run the simulation in stepping mode, showing the served frame at every step.

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
            sim_dt = self._start(info.dt)
            return self._loop(info, end_t, max_steps, sim_dt, on_step)
        finally:
            self.stop()

    def _start(self, dt: float) -> float:
        sim = self.sim
        with self._remote("starting the simulation"):
            if sim.getSimulationState() != sim.simulation_stopped:
                log.warning("the simulation was already running; stopping it first")
                self._stop_and_wait()
            self._match_time_step(dt)
            # The remote API server resets stepping whenever the simulation stops: set it anew.
            sim.setStepping(True)
            sim.startSimulation()
            self._running = True
            sim_dt = float(sim.getSimulationTimeStep())
        return sim_dt

    def _match_time_step(self, dt: float) -> None:
        sim = self.sim
        try:
            current = float(sim.getSimulationTimeStep())
            if abs(current - dt) > 1e-12:
                sim.setFloatParam(sim.floatparam_simulation_time_step, dt)
                # The user's simulator setting changes (and stays changed): say so, once.
                log.warning(
                    "changed the simulator's time step from %g s to %g s (the scene's dt); "
                    "it stays so after the run",
                    current,
                    dt,
                )
        except AttributeError:
            log.warning("cannot set the simulator's time step to %g s; keeping its own", dt)
        except Exception as exc:
            if type(exc) is not Exception:
                raise
            log.warning("simulator refused time step %g s (%s); keeping its own", dt, exc)

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
            if max_steps is not None and steps >= max_steps:
                reason = MAX_STEPS
                break
            start = time.perf_counter()
            with self._remote("reading the simulation time"):
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
            with self._remote("moving the spheres"):
                self.move(positions)
            moved = time.perf_counter()
            with self._remote("stepping the simulation"):
                sim.step()
            stepped = time.perf_counter()
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

    def stop(self) -> None:
        """Stop the simulation if this lattice started it (and the simulator still answers)."""
        if self._running and not self._dead:
            with self._remote("stopping the simulation"):
                self._stop_and_wait()
        self._running = False

    def _stop_and_wait(self) -> None:
        # CoppeliaSim stops during its next simulation pass, not within the call: wait for it,
        # or a following start (or removal) could meet a simulation still stopping.
        sim = self.sim
        sim.stopSimulation()
        deadline = time.monotonic() + STOP_WAIT_S
        while sim.getSimulationState() != sim.simulation_stopped:
            if time.monotonic() > deadline:
                raise SimulatorError(f"the simulation did not stop within {STOP_WAIT_S:g} s")
            time.sleep(0.01)

    def close(self) -> None:
        """Stop the simulation and, unless ``keep``, remove the lattice (no call if dead)."""
        try:
            self.stop()
        finally:
            if not self.keep:
                self.remove()

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
            log.warning("cleanup after an error failed: %s", cleanup_error)

    # -- helpers -----------------------------------------------------------------------------

    def _info(self) -> SceneInfo:
        if self.info is None:
            raise RuntimeError("build() first")
        return self.info

    @contextmanager
    def _remote(self, doing: str) -> Iterator[None]:
        if self._dead:
            raise SimulatorError(f"the connection to {self.address} was lost earlier")
        try:
            with _translate_remote_errors(self.address, self.timeout, doing):
                yield
        except SimulatorConnectionLost:
            self._dead = True
            raise


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
    on_step: Callable[[int, float], None] | None = None,
) -> RunResult:
    """Connect to a membrane server and to CoppeliaSim, build the lattice, run, clean up.

    Arguments as in :class:`SphereLattice` and :meth:`SphereLattice.run`.

    Raises:
        SimulatorTimeout: CoppeliaSim did not answer within ``sim_timeout``.
        SimulatorError: CoppeliaSim refused a call.
        membrane_client.Timeout / ServerError: the membrane server did not answer, or refused.
    """
    link = connect_simulator(sim_host, sim_port, sim_timeout)
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
            ) as lattice,
        ):
            lattice.build()
            return lattice.run(duration=duration, max_steps=max_steps, on_step=on_step)
    finally:
        link.close()
