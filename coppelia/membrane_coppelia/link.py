"""The connection to CoppeliaSim's ZeroMQ remote API: timeouts on both sides, errors, release.

Two timeouts guard a run, one on each side of the socket:

- ours (``timeout``, ``RCVTIMEO``/``SNDTIMEO``): how long we wait for one reply before calling
  CoppeliaSim gone. The 2.0.4 client sets none, so a dead CoppeliaSim would hang it forever.
- the add-on's (``remote_timeout``): how long the ZeroMQ remote API add-on keeps a client that has
  gone silent. A stepping client holds every simulation pass until it calls ``sim.step`` again;
  one that vanished (SIGKILL, a crash, a pulled cable) holds the simulator until the add-on
  forgets it. The Python client sends 600 s with its first request, so the simulator would look
  frozen for ten minutes; :func:`connect_simulator` sends ``remote_timeout`` instead (it must be
  set before the first request: the add-on reads it once, when it first sees the client).

After a timeout, or an interrupt in the middle of a request, the client's REQ socket is stuck
mid-exchange: it is never used again (:class:`CallGuard`). :func:`release_simulator` stops the
simulation from a fresh connection, which resets every client's stepping in the add-on.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import cbor2
import zmq

from membrane_client.errors import MembraneError, UserError

__all__ = [
    "DEFAULT_REMOTE_TIMEOUT",
    "DEFAULT_SIM_HOST",
    "DEFAULT_SIM_PORT",
    "DEFAULT_SIM_TIMEOUT",
    "STOP_WAIT_S",
    "CallGuard",
    "ObjectNotFound",
    "SimulatorConnectionLost",
    "SimulatorError",
    "SimulatorLink",
    "SimulatorTimeout",
    "apply_timeouts",
    "connect_simulator",
    "one_line",
    "release_simulator",
    "stop_and_wait",
    "translate_remote_errors",
]

log = logging.getLogger(__name__)

DEFAULT_SIM_HOST = "127.0.0.1"
DEFAULT_SIM_PORT = 23000  # the add-on's default (plus the instance's index from 4.7: see docs)
DEFAULT_SIM_TIMEOUT = 5.0  # how long we wait for one reply
# Long enough for a slow step (a membrane query, a first-time build of 10,000 spheres between two
# requests), short enough that a killed adapter frees the simulator soon.
DEFAULT_REMOTE_TIMEOUT = 20.0
STOP_WAIT_S = 10.0  # how long a stop may take before we call it a failure
END = "_*end*_"  # tells the add-on that a client leaves (it forgets it at once)
END_WAIT_MS = 500


class SimulatorError(MembraneError):
    """CoppeliaSim refused a call, or the connection to it failed."""


class SimulatorConnectionLost(SimulatorError):
    """The connection to CoppeliaSim is unusable (its REQ socket is stuck): make no more calls."""


class SimulatorTimeout(SimulatorConnectionLost):
    """CoppeliaSim did not answer within the timeout."""


class ObjectNotFound(SimulatorError, UserError):
    """A scene object the user named (``--probe``) is not in CoppeliaSim's scene."""


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
    """A connection to CoppeliaSim's ZeroMQ remote API: the client and its ``sim`` object.

    ``broken`` is set when the socket may be stuck mid-exchange (a timeout, an interrupt during
    a request); a broken link only closes.
    """

    remote: Any
    sim: Any
    address: str
    timeout: float
    remote_timeout: float = DEFAULT_REMOTE_TIMEOUT
    broken: bool = False

    def close(self) -> None:
        """Tell the add-on we leave (when the socket allows it), then close at once (LINGER 0).

        Leaving explicitly frees the add-on's record of this client now rather than after
        ``remote_timeout``; it is best effort and waits at most half a second.
        """
        socket = self.remote.socket
        if not self.broken and not socket.closed:
            try:
                socket.send(cbor2.dumps({"func": END, "args": [], "uuid": self.remote.uuid}))
                if socket.poll(END_WAIT_MS):
                    socket.recv()
            except zmq.ZMQError as exc:  # e.g. a REQ socket waiting for a reply: leave it
                log.debug("could not say goodbye to %s: %s", self.address, exc)
        socket.close(linger=0)


def connect_simulator(
    host: str = DEFAULT_SIM_HOST,
    port: int = DEFAULT_SIM_PORT,
    timeout: float = DEFAULT_SIM_TIMEOUT,
    remote_timeout: float = DEFAULT_REMOTE_TIMEOUT,
) -> SimulatorLink:
    """Connect to CoppeliaSim (or the stand-in) and fetch its ``sim`` object.

    Args:
        timeout: seconds we wait for each reply.
        remote_timeout: seconds the add-on waits for a silent client before forgetting it (and
            releasing the simulation it holds in stepping mode).

    Raises:
        SimulatorTimeout: nothing answered within ``timeout`` seconds.
        ModuleNotFoundError: the ``coppelia`` extra is not installed.
    """
    from coppeliasim_zmqremoteapi_client import RemoteAPIClient

    if not 0 < port < 65536:
        raise ValueError(f"the simulator port must be in 1..65535, got {port}")
    if not remote_timeout > 0:
        raise ValueError(f"the remote timeout must be > 0 seconds, got {remote_timeout}")
    address = f"tcp://{host}:{port}"
    remote = RemoteAPIClient(host, port)
    remote.timeout = remote_timeout  # sent with the first request: before require()
    apply_timeouts(remote, timeout)
    link = SimulatorLink(remote, None, address, timeout, remote_timeout)
    try:
        with translate_remote_errors(address, timeout, "fetching the sim API"):
            link.sim = remote.require("sim")
    except BaseException:
        link.broken = True
        link.close()
        raise
    return link


@contextmanager
def translate_remote_errors(address: str, timeout: float | None, doing: str) -> Iterator[None]:
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
        raise SimulatorError(f"CoppeliaSim refused a call while {doing}: {one_line(exc)}") from None


class CallGuard:
    """The remote calls made on one connection: their errors become :class:`SimulatorError`, and
    once the connection is unusable none is made on it again.

    Unusable means a lost connection (a timeout, a ZeroMQ error) or a call interrupted by a
    signal: its REQ socket may be stuck mid-exchange, and the next send would fail or hang.
    """

    def __init__(self, address: str = "CoppeliaSim", timeout: float | None = None) -> None:
        self.address = address
        self.timeout = timeout
        self.dead = False

    @contextmanager
    def calling(self, doing: str) -> Iterator[None]:
        """Make remote calls; ``doing`` names them in errors ("while <doing>")."""
        if self.dead:
            raise SimulatorConnectionLost(f"the connection to {self.address} was lost earlier")
        try:
            with translate_remote_errors(self.address, self.timeout, doing):
                yield
        except SimulatorConnectionLost:
            self.dead = True
            raise
        except BaseException as exc:
            if not isinstance(exc, Exception):  # an interrupt: the REQ socket may be stuck
                self.dead = True
            raise


def one_line(exc: BaseException) -> str:
    """An error reply as one line (the add-on encodes Lua newlines and tabs as _=NL=_, _=TB=_)."""
    text = str(exc).replace("_=NL=_", " ").replace("_=TB=_", " ")
    return " ".join(text.split()) or type(exc).__name__


def stop_and_wait(sim: Any, wait: float = STOP_WAIT_S) -> None:
    """Ask CoppeliaSim to stop and wait until it reports stopped.

    CoppeliaSim stops over its next passes (about-to-stop, last-before-stop), not within the
    call; a following start, or a removal, must not meet a simulation still stopping. The
    add-on resets every client's stepping level when ``sim.stopSimulation`` is called.
    """
    sim.stopSimulation()
    deadline = time.monotonic() + wait
    while sim.getSimulationState() != sim.simulation_stopped:
        if time.monotonic() > deadline:
            raise SimulatorError(f"the simulation did not stop within {wait:g} s")
        time.sleep(0.01)


def release_simulator(
    host: str,
    port: int,
    timeout: float = DEFAULT_SIM_TIMEOUT,
    remote_timeout: float = DEFAULT_REMOTE_TIMEOUT,
) -> None:
    """Stop the simulation from a fresh connection (the old one being unusable).

    Stopping resets every client's stepping level in the add-on, so a simulator held by a
    stepping client that will never step again runs free (and stops) at once.
    """
    link = connect_simulator(host, port, timeout, remote_timeout)
    try:
        with translate_remote_errors(link.address, timeout, "stopping the simulation"):
            stop_and_wait(link.sim)
    finally:
        link.close()
