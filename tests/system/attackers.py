"""Tools for the attack tests: a watched `membrane serve`, a good client that checks every frame
it gets, and raw peers that misbehave on purpose (loopback only).

The server runs in its own process so that its memory is measured alone (VmRSS from /proc) and
its death is seen; a watchdog kills it past a memory ceiling, so that an attack that works costs
a failed test, never the machine.
"""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import zmq

from membrane_client import Client
from membrane_client.errors import MembraneError
from membrane_server.dispatch import ServedScene

MEMBRANE = [sys.executable, "-m", "membrane_cli"]
MiB = 1024 * 1024
# The watchdog kills a server whose RSS passes this: no attack test needs a tenth of it.
KILL_AT_BYTES = 1536 * MiB
_START_TIMEOUT_S = 60.0  # a cold `membrane serve` imports scipy and onnxruntime


def rss_bytes(pid: int) -> int:
    """Resident memory of a process (VmRSS), in bytes; 0 once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0
    for line in status.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


class WatchedServer:
    """`membrane -v serve` in a subprocess, its RSS sampled every 20 ms (peak kept), killed by a
    watchdog past ``kill_at`` bytes.

    Args:
        scenes: ``--scene`` values.
        extra: More `membrane serve` arguments.
        preexec: Run in the child before exec (e.g. to lower a resource limit).
    """

    def __init__(
        self,
        scenes: list[str],
        extra: list[str] | None = None,
        kill_at: int = KILL_AT_BYTES,
        preexec: Callable[[], object] | None = None,
    ) -> None:
        command = [*MEMBRANE, "-v", "serve", "--bind", "tcp://127.0.0.1:*"]
        for scene in scenes:
            command += ["--scene", scene]
        self.process = subprocess.Popen(
            [*command, *(extra or [])],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=preexec,
        )
        self.log: list[str] = []
        self._stdout: queue.Queue[str] = queue.Queue()
        self._kill_at = kill_at
        self.killed_for_memory = False
        self.peak = 0
        self._sampling = threading.Event()
        threading.Thread(target=self._pump_stdout, daemon=True).start()
        threading.Thread(target=self._pump_stderr, daemon=True).start()
        self.address = self._wait_listening()
        self.baseline = rss_bytes(self.process.pid)
        threading.Thread(target=self._watch, daemon=True).start()

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def rss(self) -> int:
        return rss_bytes(self.pid)

    def high_water(self) -> int:
        """The most resident memory the process ever had (VmHWM), load included, in bytes."""
        status = Path(f"/proc/{self.pid}/status").read_text()
        line = next(line for line in status.splitlines() if line.startswith("VmHWM:"))
        return int(line.split()[1]) * 1024

    def reset_peak(self) -> None:
        """Start a new peak from the current RSS."""
        self.peak = self.rss()

    def growth(self) -> int:
        """Peak RSS since start (or the last ``reset_peak``) above the RSS once listening."""
        return max(0, self.peak - self.baseline)

    def tracebacks(self) -> list[str]:
        return [line for line in self.log if "Traceback" in line]

    def close(self) -> None:
        self._sampling.set()
        if self.alive:
            self.process.kill()
        self.process.wait(10)

    def _wait_listening(self) -> str:
        deadline = time.monotonic() + _START_TIMEOUT_S
        while time.monotonic() < deadline:
            try:
                line = self._stdout.get(timeout=0.5)
            except queue.Empty:
                if not self.alive:
                    break
                continue
            if line.startswith("membrane serve: listening on "):
                return line.split("listening on ", 1)[1].split()[0]
        self.close()
        raise AssertionError(f"server did not start: {self.log[-20:]}")

    def _pump_stdout(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self._stdout.put(line.rstrip("\n"))

    def _pump_stderr(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.log.append(line.rstrip("\n"))

    def _watch(self) -> None:
        while not self._sampling.wait(0.02) and self.alive:
            rss = self.rss()
            self.peak = max(self.peak, rss)
            if rss > self._kill_at:
                self.killed_for_memory = True
                self.process.kill()
                return


@dataclass
class GoodClient:
    """A well-behaved simulator loop in a thread: queries its scene's times in turn, checks each
    frame byte for byte against the scene's own evaluator (loaded in this process), and counts.

    Args:
        address: The server.
        scene: The scene's name or file (as given to the server).
        timeout: Per-request timeout (a failure when exceeded).
    """

    address: str
    scene: str
    timeout: float = 2.0
    answered: int = 0
    failures: list[str] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def start(self) -> GoodClient:
        served = ServedScene.load(self.scene)
        times = [served.timeline.step_time(k) for k in range(0, served.timeline.last_step + 1)]
        expected = {t: served.query(t)["z"]["data"] for t in times}
        self._thread = threading.Thread(target=self._run, args=(served.name, expected), daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(30)

    def _run(self, name: str, expected: dict[float, bytes]) -> None:
        with Client(self.address, timeout=self.timeout, scene=name) as client:
            while not self._stop.is_set():
                for t, data in expected.items():
                    if self._stop.is_set():
                        return
                    try:
                        frame = client.query(t)
                    except MembraneError as exc:
                        self.failures.append(f"t={t}: {type(exc).__name__}: {exc}")
                        continue
                    if frame.z.astype("<f4").tobytes() != data:
                        self.failures.append(f"t={t}: frame differs from the evaluator's")
                    self.answered += 1
                    time.sleep(0.002)


# -- raw peers ---------------------------------------------------------------------------------


def dealer(address: str, timeout_ms: int = 5000) -> zmq.Socket[bytes]:
    """A raw DEALER for requests of one's own making (LINGER 0, a receive timeout)."""
    socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.DEALER)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, timeout_ms)
    socket.connect(address)
    return socket


def silent_dealers(address: str, count: int) -> list[zmq.Socket[bytes]]:
    """``count`` DEALER connections that will never read a reply (a one-message receive queue,
    a small kernel buffer), for sending requests whose replies pile up at the server."""
    context: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    sockets = []
    for _ in range(count):
        dealer: zmq.Socket[bytes] = context.socket(zmq.DEALER)
        dealer.setsockopt(zmq.LINGER, 0)
        dealer.setsockopt(zmq.RCVHWM, 1)
        dealer.setsockopt(zmq.RCVBUF, 4096)
        dealer.connect(address)
        sockets.append(dealer)
    return sockets
