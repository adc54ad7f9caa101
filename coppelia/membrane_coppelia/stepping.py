"""CoppeliaSim in stepping mode, started and stopped by this client and never left held.

A client in stepping mode holds every simulation pass until it calls ``sim.step()`` again, so
whoever starts a stepped simulation owes CoppeliaSim a stop. :class:`SteppedSimulation` sets the
scene's time step, enters stepping mode and starts; steps; and stops, waiting until CoppeliaSim
reports it stopped (the add-on then resets every client's stepping level).

When its own connection became unusable (a timeout, an interrupt in the middle of a request:
:class:`~membrane_coppelia.link.CallGuard`), it stops from a fresh one instead (``reconnect``),
so that an interrupted run never leaves CoppeliaSim held; what else must be undone over that
fresh connection (a force signal set to 0, the lattice removed) runs there too.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from membrane_coppelia.compat import SimCalls
from membrane_coppelia.link import (
    CallGuard,
    SimulatorError,
    SimulatorLink,
    one_line,
    stop_and_wait,
    translate_remote_errors,
)

__all__ = ["SteppedSimulation"]

log = logging.getLogger(__name__)


class SteppedSimulation:
    """The simulation this client runs in stepping mode.

    Args:
        sim: the ``sim`` object of a ``RemoteAPIClient``.
        guard: the calls on ``sim``'s connection (it knows when that connection is unusable).
        reconnect: opens a fresh connection to the same CoppeliaSim, to stop the simulation
            when this one became unusable; without it such a stop is an error.

    Attributes:
        running: this client started the simulation and has not stopped it yet.
        started: this client started the simulation at least once.
    """

    def __init__(
        self,
        sim: Any,
        guard: CallGuard,
        reconnect: Callable[[], SimulatorLink] | None = None,
    ) -> None:
        self.sim = sim
        self.guard = guard
        self.reconnect = reconnect
        self.running = False
        self.started = False
        self._recover_actions: list[Callable[[Any], None]] = []

    def on_recover(self, action: Callable[[Any], None]) -> None:
        """Also run ``action(sim)`` when cleaning up over a fresh connection (after the stop;
        best effort: a failure is logged)."""
        self._recover_actions.append(action)

    def start(self, dt: float, calls: SimCalls | None = None) -> float:
        """Set the time step to ``dt``, enter stepping mode and start; returns the simulator's dt.

        Raises:
            TimeStepRefused: CoppeliaSim would not take ``dt``.
        """
        sim = self.sim
        with self.guard.calling("starting the simulation"):
            if sim.getSimulationState() != sim.simulation_stopped:
                log.warning("the simulation was already running; stopping it first")
                stop_and_wait(sim)
            self._match_time_step(dt, calls)
            # From here on cleaning up means stopping (which also resets our stepping level):
            # marked first, so that an interrupt inside either call still leads to a stop.
            self.running = self.started = True
            # The remote API add-on resets stepping whenever the simulation stops: set it anew.
            sim.setStepping(True)
            sim.startSimulation()
            sim_dt = float(sim.getSimulationTimeStep())
        return sim_dt

    def _match_time_step(self, dt: float, calls: SimCalls | None) -> None:
        current = float(self.sim.getSimulationTimeStep())
        if abs(current - dt) <= 1e-12:
            return
        (calls or SimCalls(self.sim)).set_time_step(dt)
        # The user's simulator setting changes (and stays changed): say so, once.
        log.warning(
            "changed the simulator's time step from %g s to %g s (the scene's dt); "
            "it stays so after the run",
            current,
            dt,
        )

    def step(self) -> None:
        """One simulation step (``sim.step()``: returns when CoppeliaSim has taken it)."""
        with self.guard.calling("stepping the simulation"):
            self.sim.step()

    def stop(self) -> None:
        """Stop the simulation if this client started it (from a fresh connection if this one
        is unusable and ``reconnect`` was given)."""
        if not self.running:
            return
        if not self.guard.dead:
            with self.guard.calling("stopping the simulation"):
                stop_and_wait(self.sim)
        elif self.reconnect is not None:
            self.recover()
        else:
            raise self.lost()
        self.running = False

    def recover(self, remove: Callable[[Any], None] | None = None) -> None:
        """Over a fresh connection: stop (if running), run the :meth:`on_recover` actions, then
        ``remove(sim)``; nothing at all when there is neither a stop nor a removal to make."""
        if self.reconnect is None:
            raise RuntimeError("recover() needs reconnect")
        if not self.running and remove is None:
            return
        log.info("cleaning up over a fresh connection to %s", self.guard.address)
        link = self.reconnect()
        try:
            with translate_remote_errors(link.address, link.timeout, "cleaning up"):
                if self.running:
                    stop_and_wait(link.sim)
                    self.running = False
                for action in self._recover_actions:
                    try:
                        action(link.sim)
                    except Exception as exc:
                        if type(exc) is not Exception:  # not the remote client's error reply
                            raise
                        log.warning("cleanup over a fresh connection: %s", one_line(exc))
                if remove is not None:
                    remove(link.sim)
        finally:
            link.close()

    def lost(self) -> SimulatorError:
        """The error for a stop that cannot be made (an unusable connection, no reconnect)."""
        return SimulatorError(
            f"the connection to {self.guard.address} was lost: the simulation may still run"
        )
