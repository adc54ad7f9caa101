"""The stand-in's model of CoppeliaSim's ZeroMQ remote API add-on: its protocol and its loop.

It speaks version 2 of the remote API protocol, the one ``coppeliasim-zmqremoteapi-client``
2.0.4 uses, so that the real client talks to it unmodified:

- a REP socket; every message is one CBOR map;
- requests ``{"func": NAME, "args": [...], "argsL": n, "uuid": ...}`` (the first of a client also
  carries ``ver``, ``lang`` and ``timeout``; ``ver`` is not checked, as in the add-on); replies
  ``{"ret": [values]}`` or ``{"err": message}``; ``_*end*_`` makes the add-on forget a client;
- ``zmqRemoteApi.require`` / ``zmqRemoteApi.info`` for ``sim``: the info reply maps each
  function name to ``{"func": {}}`` and each constant to ``{"const": value}``.

It models the add-on's loop (``ZMQ remote API server.lua``; docs/COPPELIA.md says which version
was read), because that is where a simulator gets held or released:

- CoppeliaSim runs passes. In each, the add-on handles requests until its message window closes
  (2 ms per client while the simulation runs, 50 ms while stopped, counted from the first
  message of the pass). While the simulation runs, a pass does not end while any client in
  stepping mode (``sim.setStepping(True)``, per client) has not asked for the next step.
- ``sim.step()`` answers ``_*wait*_``, and again to each ``_*executed*_``, until the pass has
  ended: while running, one wait and one more for each ``_*executed*_`` that arrives within the
  pass's window (usually two or more; one when the client answers later than that); one while
  stopped.
- ``sim.stopSimulation`` resets every client's stepping; the simulation then stops over several
  passes (:class:`~membrane_coppelia.standin.scene.FakeScene`).
- A client unheard of for longer than its ``timeout`` (sent with its first request; 600 s when
  none) is forgotten, one per pass: a stepping client that vanished holds the simulation until
  then, and no longer.

Behind it a :class:`~membrane_coppelia.standin.scene.FakeScene` plays one release (4.6 to
4.9). It measures round trips and our own overhead, nothing of CoppeliaSim's own cost.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

import cbor2
import zmq

from membrane_coppelia.standin.scene import CallRefused, FakeScene

__all__ = [
    "DEFAULT_CLIENT_TIMEOUT",
    "PROTOCOL_VERSION",
    "CoppeliaStandin",
    "RemoteApiProtocol",
    "RemoteClient",
]

log = logging.getLogger(__name__)

PROTOCOL_VERSION = 2
WAIT = "_*wait*_"
EXECUTED = "_*executed*_"
END = "_*end*_"
DEFAULT_CLIENT_TIMEOUT = 600.0  # the add-on's default: 10 * 60 s
QUEUE_RUNNING_S = 0.002  # the add-on's message window per client while the simulation runs
QUEUE_IDLE_S = 0.05  # ... and while it is stopped
PASS_POLL_S = 0.001  # a pass without messages (the real loop spins; the stand-in naps)
IDLE_POLL_S = 0.005


@dataclass
class RemoteClient:
    """What the add-on keeps about one client (its ``uuid``)."""

    uuid: str
    timeout: float
    idle_since: float
    stepping: int = 0  # the stepping level: > 0 holds each pass until the client steps
    desired_step: int = 0  # the pass the client lets the simulation reach
    in_step: int | None = None  # the pass its pending sim.step began in
    step_running: bool = False  # whether the simulation ran when that sim.step began
    waits: int = 0  # _*wait*_ replies sent to it

    def holds(self, current_step: int) -> bool:
        """Whether this client keeps the current pass from ending."""
        return self.stepping > 0 and self.desired_step <= current_step


class RemoteApiProtocol:
    """The add-on's side of the protocol: requests to replies, clients and their stepping.

    No sockets here: :class:`CoppeliaStandin` feeds it requests, sends back what it returns and
    ends passes. Thread-safe for readers (:meth:`snapshot`).
    """

    def __init__(self, scene: FakeScene, clock: Any = time.monotonic) -> None:
        self.scene = scene
        self.clock = clock
        self.clients: dict[str, RemoteClient] = {}
        self.current_step = 0
        self.forgotten: list[str] = []  # uuids forgotten after their timeout, in order
        self._functions = scene.functions()
        self._required: set[str] = set()
        self._lock = threading.Lock()

    # -- what tests look at ------------------------------------------------------------------

    def snapshot(self) -> dict[str, RemoteClient]:
        """A copy of every client's record."""
        with self._lock:
            return {uuid: replace(client) for uuid, client in self.clients.items()}

    def held(self) -> bool:
        """Whether some client in stepping mode holds the running simulation."""
        with self._lock:
            return self.scene.running and self._holds()

    # -- the loop's hooks --------------------------------------------------------------------

    def holds(self) -> bool:
        with self._lock:
            return self._holds()

    def _holds(self) -> bool:
        return any(c.holds(self.current_step) for c in self.clients.values())

    def forget_idle(self) -> None:
        """Forget one client unheard of for longer than its timeout (as the add-on, one per
        pass)."""
        now = self.clock()
        with self._lock:
            for uuid, client in self.clients.items():
                if now - client.idle_since > client.timeout:
                    del self.clients[uuid]
                    self.forgotten.append(uuid)
                    log.info("forgot client %s after %g s of silence", uuid, client.timeout)
                    return

    def end_pass(self) -> None:
        """A simulation pass ends: the add-on's step counter and the scene advance."""
        with self._lock:
            self.current_step += 1
            self.scene.end_pass()
            if not self.scene.running:
                self.current_step = 0  # sysCall_afterSimulation

    # -- requests ----------------------------------------------------------------------------

    def reply(self, request: object) -> dict[str, Any]:
        """The reply to one request (never raises)."""
        if not isinstance(request, dict) or "uuid" not in request:
            # What the add-on answers to clients of an older protocol.
            return {
                "success": False,
                "error": "The client ZeroMQ remote API version does not match CoppeliaSim's",
            }
        func = request.get("func")
        args = request.get("args") or []
        uuid = str(request["uuid"])
        if not isinstance(func, str) or not isinstance(args, list):
            return {"err": "a request needs 'func' (a string) and 'args' (an array)"}
        with self._lock:
            if func == END:
                self.clients.pop(uuid, None)
                return {}
            client = self._client(uuid, request.get("timeout"))
            reply = self._reply(client, func, args)
            client.idle_since = self.clock()
            return reply

    def _client(self, uuid: str, timeout: object) -> RemoteClient:
        client = self.clients.get(uuid)
        if client is None:  # the timeout counts only when the add-on first sees the client
            seconds = float(timeout) if isinstance(timeout, int | float) else DEFAULT_CLIENT_TIMEOUT
            client = RemoteClient(uuid, seconds, self.clock(), desired_step=self.current_step)
            self.clients[uuid] = client
        return client

    def _reply(self, client: RemoteClient, func: str, args: list[Any]) -> dict[str, Any]:
        if client.in_step is not None:
            return self._continue_step(client, func)
        self.scene.calls[func] += 1
        if func == "sim.step":
            return self._begin_step(client)
        try:
            return {"ret": _as_ret(self._call(client, func, args))}
        except CallRefused as exc:
            return {"err": f"{exc} (in function '{func}')"}
        except TypeError as exc:  # wrong number of arguments
            return {"err": f"invalid arguments: {exc} (in function '{func}')"}

    def _begin_step(self, client: RemoteClient) -> dict[str, Any]:
        running = self.scene.running
        if running and client.stepping > 0:
            client.desired_step = self.current_step + 1
        client.in_step, client.step_running = self.current_step, running
        client.waits += 1
        return {"func": WAIT, "args": []}

    def _continue_step(self, client: RemoteClient, func: str) -> dict[str, Any]:
        if func != EXECUTED:
            client.in_step = None
            return {"err": f"expected {EXECUTED!r} during sim.step, got {func!r}"}
        if client.step_running and client.in_step == self.current_step:
            client.waits += 1  # the pass has not ended yet: wait again
            return {"func": WAIT, "args": []}
        client.in_step = None
        return {"ret": []}

    def _call(self, client: RemoteClient, func: str, args: list[Any]) -> Any:
        if func == "zmqRemoteApi.require":
            return self._require(args)
        if func == "zmqRemoteApi.info":
            return self._info(args)
        module, _, name = func.partition(".")
        if module != "sim" or (name not in self._functions and name != "setStepping"):
            raise CallRefused(f"No such function: {func}")
        if module not in self._required:
            raise CallRefused(f"module {module!r} was not required")
        if name == "setStepping":
            return self._set_stepping(client, *args)
        if name == "stopSimulation":
            for other in self.clients.values():  # the add-on's wrapper of sim.stopSimulation
                other.stepping = 0
                other.desired_step = self.current_step + 10
        return self._functions[name](*args)

    def _set_stepping(self, client: RemoteClient, enabled: bool) -> int:
        previous = client.stepping
        if enabled:
            if client.stepping == 0:
                client.desired_step = self.current_step
            client.stepping += 1
        elif client.stepping > 0:
            client.stepping -= 1
        return previous

    def _require(self, args: list[Any]) -> None:
        if args != ["sim"]:
            raise CallRefused(f"module not found: {args!r} (the stand-in offers 'sim' only)")
        self._required.add("sim")

    def _info(self, args: list[Any]) -> dict[str, dict[str, Any]]:
        if args != ["sim"] or "sim" not in self._required:
            raise CallRefused(f"no such object: {args!r}")
        info: dict[str, dict[str, Any]] = {name: {"func": {}} for name in self._functions}
        info["step"] = {"func": {}}
        info["setStepping"] = {"func": {}}
        info.update({name: {"const": value} for name, value in self.scene.constants().items()})
        return info


def _as_ret(value: Any) -> list[Any]:
    if value is None:
        return []
    if isinstance(value, tuple):
        return list(value)
    return [value]


class CoppeliaStandin:
    """The stand-in server: a REP socket on 127.0.0.1 answering from its own thread, which runs
    the add-on's pass loop.

    Args:
        host: interface to bind (loopback by default).
        port: TCP port; 0 picks a free one (see :attr:`address`).
        dt: the scene's initial simulation time step in seconds.
        answer_limit: stop answering (keep the socket, never reply) after this many replies;
            ``None`` answers forever. Simulates a CoppeliaSim that hangs.
        scripts: offer script calls (see :class:`FakeScene`).
        version: the CoppeliaSim release played: "4.6", "4.7", "4.8" or "4.9".
        init_delay_passes: passes before ``sim.initScript`` takes effect (see FakeScene).

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
        version: str = "4.9",
        init_delay_passes: int = 0,
    ) -> None:
        self.scene = FakeScene(
            dt, scripts=scripts, version=version, init_delay_passes=init_delay_passes
        )
        self.protocol = RemoteApiProtocol(self.scene)
        self.answer_limit = answer_limit
        self.replies = 0
        self.passes = 0
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

    def stepping_levels(self) -> dict[str, int]:
        """Each known client's stepping level, by uuid."""
        return {uuid: c.stepping for uuid, c in self.protocol.snapshot().items()}

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

    # -- the add-on's loop -------------------------------------------------------------------

    def serve(self) -> None:
        """Run passes until :meth:`stop` (or a signal) sets the stop flag."""
        while not self._stop.is_set():
            if self._hung():
                self._stop.wait(0.05)  # hung: leave requests unanswered
                continue
            if self.scene.running:
                self._simulation_pass()
            else:
                self._handle_queue(running=False)
            self.scene.tick()
            self.passes += 1

    def _simulation_pass(self) -> None:
        # sysCall_actuation: the pass ends once no stepping client holds it.
        while not self._stop.is_set():
            self._handle_queue(running=True)
            if self._hung() or not self.protocol.holds():
                break
            self.scene.tick()
        self.protocol.end_pass()

    def _handle_queue(self, running: bool) -> None:
        # zmqRemoteApi.handleQueue: forget one idle client, then answer requests until the
        # message window (counted from the pass's start) closes; without requests, return.
        self.protocol.forget_idle()
        start = time.monotonic()
        messages, clients = 0, set[str]()
        while not self._stop.is_set() and not self._hung():
            if messages == 0:
                window = -1.0
                wait = PASS_POLL_S if running else IDLE_POLL_S
            else:
                window = QUEUE_RUNNING_S * len(clients) if running else QUEUE_IDLE_S
                wait = max(0.0, window - (time.monotonic() - start))
            if self._socket.poll(round(wait * 1000)):
                uuid = self._answer_one()
                messages += 1
                clients.add(uuid)
                continue
            if time.monotonic() - start > window:
                return

    def _answer_one(self) -> str:
        raw = self._socket.recv()
        request, reply = self._reply(raw)
        self._socket.send(cbor2.dumps(reply))
        self.replies += 1
        return str(request.get("uuid")) if isinstance(request, dict) else "?"

    def _hung(self) -> bool:
        return self.answer_limit is not None and self.replies >= self.answer_limit

    def _reply(self, raw: bytes) -> tuple[object, dict[str, Any]]:
        try:
            request = cbor2.loads(raw)
        except (cbor2.CBORDecodeError, ValueError) as exc:
            return None, {"err": f"cannot decode the request as CBOR: {exc}"}
        reply = self.protocol.reply(request)
        log.debug("%s -> %s", request.get("func") if isinstance(request, dict) else "?", reply)
        return request, reply
