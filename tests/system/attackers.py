"""Tools for the attack tests: a watched `membrane serve`, a good client that checks every frame
it gets, and raw peers that misbehave on purpose (loopback only).

The server runs in its own process so that its memory is measured alone (VmRSS from /proc) and
its death is seen; a watchdog kills it past a memory ceiling, so that an attack that works costs
a failed test, never the machine.
"""

from __future__ import annotations

import fcntl
import json
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zmq

from membrane_client import Client
from membrane_client.errors import MembraneError
from membrane_server.served import ServedScene

MEMBRANE = [sys.executable, "-m", "membrane_cli"]
MiB = 1024 * 1024
# The watchdog kills a server whose RSS passes this: no attack test needs a tenth of it.
KILL_AT_BYTES = 1536 * MiB
_START_TIMEOUT_S = 60.0  # a cold `membrane serve` imports scipy and onnxruntime
# Requests carrying this in their payload make the server's request handling raise (a bug on
# demand, for the tests of what a bug costs: one reply, one log line at most per kind).
FAULT_MARK = b"inject-a-fault"
# `membrane` with that bug: run it as WatchedServer(..., membrane=FAULTY_MEMBRANE).
FAULTY_MEMBRANE = [
    sys.executable,
    "-c",
    f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r}); "
    "import attackers; attackers.serve_with_injected_faults()",
]


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
        membrane: The `membrane` command to run (default: this interpreter's; see
            ``FAULTY_MEMBRANE``).
        read_stderr: False leaves the server's stderr pipe unread until ``read_stderr()``.
        stderr_pipe_bytes: Resize that pipe (Linux; at least a page).
    """

    def __init__(
        self,
        scenes: list[str],
        extra: list[str] | None = None,
        kill_at: int = KILL_AT_BYTES,
        preexec: Callable[[], object] | None = None,
        *,
        membrane: list[str] | None = None,
        read_stderr: bool = True,
        stderr_pipe_bytes: int | None = None,
    ) -> None:
        command = [*(membrane or MEMBRANE), "-v", "serve", "--bind", "tcp://127.0.0.1:*"]
        for scene in scenes:
            command += ["--scene", scene]
        self.process = subprocess.Popen(
            [*command, *(extra or [])],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=preexec,
        )
        if stderr_pipe_bytes is not None:
            assert self.process.stderr is not None
            fcntl.fcntl(self.process.stderr.fileno(), fcntl.F_SETPIPE_SZ, stderr_pipe_bytes)
        self.log: list[str] = []
        self.log_bytes = 0  # of stderr, read so far
        self._stdout: queue.Queue[str] = queue.Queue()
        self._kill_at = kill_at
        self.killed_for_memory = False
        self.peak = 0
        self._sampling = threading.Event()
        threading.Thread(target=self._pump_stdout, daemon=True).start()
        self._stderr_read = False
        if read_stderr:
            self.read_stderr()
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

    def read_stderr(self) -> None:
        """Start reading the server's stderr into ``log`` (once)."""
        if not self._stderr_read:
            self._stderr_read = True
            threading.Thread(target=self._pump_stderr, daemon=True).start()

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
            self.log_bytes += len(line.encode())
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


def serve_with_injected_faults() -> None:
    """Run the `membrane` command (arguments from ``sys.argv``) with a bug on demand: the
    dispatcher raises RuntimeError on any request whose payload holds FAULT_MARK, so that the
    server's own failure path (log, count, ``internal_error`` reply) runs. Test-only."""
    from membrane_cli.dispatcher import main
    from membrane_server.dispatch import Dispatcher

    handle, handle_many = Dispatcher.handle, Dispatcher.handle_many

    def fail_if_marked(body: Sequence[bytes]) -> None:
        """The one place the fault is raised (one kind of traceback, whichever path)."""
        if any(FAULT_MARK in bytes(part) for part in body):
            raise RuntimeError("a fault injected by the test")

    def handle_or_fail(self: Dispatcher, body: Sequence[bytes], peer: str = "") -> Any:
        fail_if_marked(body)
        return handle(self, body, peer) if peer else handle(self, body)

    def handle_many_or_fail(self: Dispatcher, requests: Sequence[tuple[Any, str]]) -> Any:
        """Requests answered together: each with the fault fails as it comes."""
        for body, peer in requests:
            fail_if_marked(body)
            yield from handle_many(self, [(body, peer)])

    Dispatcher.handle = handle_or_fail  # type: ignore[method-assign]
    Dispatcher.handle_many = handle_many_or_fail  # type: ignore[method-assign]
    sys.exit(main(sys.argv[1:]))


def request_loop(
    address: str,
    payload_hex: str,
    count: int,
    in_flight: int = 1,
    seconds: float = 60.0,
    pause_s: float = 0.0,
    timeout_ms: int = 5000,
) -> dict[str, Any]:
    """Send one request ``count`` times (or for ``seconds``) from a DEALER, ``in_flight`` at a
    time, ``pause_s`` after each reply; what came back: how many were sent and answered, the
    error codes, the longest error message, and whether a reply failed to come (``stalled``).

    Run it in a child process (``in_child``): a tight loop in the test's own process would take
    the GIL from the good client's thread, and count as the server's fault."""
    from membrane_client.protocol import decode

    payload = bytes.fromhex(payload_hex)
    socket = dealer(address, timeout_ms)
    sent = answered = longest = 0
    codes: dict[str, int] = {}
    stalled = False
    deadline = time.monotonic() + seconds
    try:
        while answered < count and not stalled:
            while sent < count and sent - answered < in_flight and time.monotonic() < deadline:
                socket.send_multipart([b"", payload])
                sent += 1
            if sent == answered:
                break
            try:
                reply = decode(socket.recv_multipart()[-1])
            except zmq.Again:
                stalled = True
                break
            answered += 1
            error = reply.get("error")
            code = "ok" if not isinstance(error, dict) else str(error.get("code"))
            codes[code] = codes.get(code, 0) + 1
            if isinstance(error, dict):
                longest = max(longest, len(str(error.get("message", ""))))
            if pause_s:
                time.sleep(pause_s)
    finally:
        socket.close()
    return {"sent": sent, "answered": answered, "codes": codes, "longest_message": longest,
            "stalled": stalled}  # fmt: skip


def in_child(function: str, timeout: float = 120.0, **arguments: Any) -> Any:
    """Run ``attackers.<function>(**arguments)`` in a child Python and return its result (JSON
    both ways)."""
    code = (
        f"import sys, json; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r}); "
        f"import attackers; print(json.dumps(attackers.{function}(**json.loads(sys.argv[1]))))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, json.dumps(arguments)],
        capture_output=True, text=True, timeout=timeout, check=False,
    )  # fmt: skip
    if done.returncode != 0:
        raise AssertionError(f"{function} failed in its child: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


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
