"""The settings of a run, shared by the film and the probe paths: where the membrane server and
CoppeliaSim are, how long to wait for each, how the lattice looks and moves, when the run ends.

:func:`~membrane_coppelia.film.drive_lattice`, :func:`~membrane_coppelia.probe.drive_probe`,
``membrane coppelia`` and the examples all take one :class:`RunOptions`, and make the
connections and the lattice from it the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from membrane_client.client import DEFAULT_ADDRESS, Client
from membrane_coppelia.lattice import LatticeStyle, SphereLattice
from membrane_coppelia.link import (
    DEFAULT_REMOTE_TIMEOUT,
    DEFAULT_SIM_HOST,
    DEFAULT_SIM_PORT,
    DEFAULT_SIM_TIMEOUT,
    SimulatorLink,
    connect_simulator,
)

__all__ = ["DEFAULT_SERVER_TIMEOUT", "RunOptions"]

DEFAULT_SERVER_TIMEOUT = 1.0


@dataclass(frozen=True)
class RunOptions:
    """How to run the served lattice in CoppeliaSim, whichever path drives it.

    Values are checked where they are used (the port when connecting, the duration when the run
    starts), with the messages those places give.
    """

    server: str = DEFAULT_ADDRESS
    """The membrane server's address (``tcp://host:port``)."""
    scene: str | None = None
    """The served scene to show, where the server hosts several (None: its default)."""
    server_timeout: float = DEFAULT_SERVER_TIMEOUT
    """Seconds to wait for each membrane server reply."""
    sim_host: str = DEFAULT_SIM_HOST
    """The host CoppeliaSim (its ZeroMQ remote API add-on) runs on."""
    sim_port: int = DEFAULT_SIM_PORT
    """The add-on's port (23000 plus the instance's index from 4.7)."""
    sim_timeout: float = DEFAULT_SIM_TIMEOUT
    """Seconds to wait for each CoppeliaSim reply before calling it gone."""
    remote_timeout: float = DEFAULT_REMOTE_TIMEOUT
    """Seconds the add-on waits for this client before forgetting it: how long a killed
    adapter can hold the simulation (the client library's own default is 600 s)."""
    style: LatticeStyle = field(default_factory=LatticeStyle)
    """Size, colour and dynamics flags of the spheres."""
    batched: bool = True
    """Move every sphere with one remote call per step (False: one call per sphere)."""
    keep: bool = False
    """Leave the lattice in the scene after the run."""
    duration: float | None = None
    """Simulation time to run to, s (None: a film runs to the scene's end, a probe on and on)."""
    max_steps: int | None = None
    """Stop after this many steps (None: no limit)."""

    def connect_simulator(self) -> SimulatorLink:
        """A connection to CoppeliaSim with these timeouts (see
        :func:`~membrane_coppelia.link.connect_simulator`)."""
        return connect_simulator(
            self.sim_host, self.sim_port, self.sim_timeout, self.remote_timeout
        )

    def client(self) -> Client:
        """A membrane client for the scene."""
        return Client(self.server, timeout=self.server_timeout, scene=self.scene)

    def lattice(self, link: SimulatorLink, client: Client) -> SphereLattice:
        """The lattice in ``link``'s CoppeliaSim, styled and moved as set here; it cleans up
        over a fresh connection (:meth:`connect_simulator`) when ``link`` becomes unusable."""
        return SphereLattice(
            link.sim,
            client,
            style=self.style,
            batched=self.batched,
            keep=self.keep,
            address=link.address,
            timeout=self.sim_timeout,
            reconnect=self.connect_simulator,
        )
