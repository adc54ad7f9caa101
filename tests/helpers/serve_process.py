"""A real `membrane serve` in a subprocess, and a reader of its output lines that never lets
the pipe fill: for tests that stop, kill or signal the server itself."""

from __future__ import annotations

import queue
import socket
import subprocess
import sys
import threading
import time
from typing import IO

__all__ = ["LINE_TIMEOUT_S", "MEMBRANE", "LineReader", "ServeProcess", "free_port_run"]

MEMBRANE = [sys.executable, "-m", "membrane_cli"]
LINE_TIMEOUT_S = 60.0  # generous: a cold `membrane serve` imports scipy and onnxruntime


class LineReader:
    """Collects a process's output lines in a background thread (so its pipe never fills)."""

    def __init__(self, stream: IO[str]) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        self._thread = threading.Thread(target=self._pump, args=(stream,), daemon=True)
        self._thread.start()

    def _pump(self, stream: IO[str]) -> None:
        for line in stream:
            self.lines.put(line.rstrip("\n"))

    def wait_for(self, prefix: str, timeout: float = LINE_TIMEOUT_S) -> str:
        """The next line starting with ``prefix`` (lines before it are kept in ``seen``)."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"no line starting {prefix!r} within {timeout} s: {self.seen}")
            try:
                line = self.lines.get(timeout=remaining)
            except queue.Empty:
                continue
            self.seen.append(line)
            if line.startswith(prefix):
                return line

    def rest(self, timeout: float = 5.0) -> list[str]:
        """Every line still to come, once the stream ends (the process exited)."""
        self._thread.join(timeout)
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return self.seen


class ServeProcess:
    """`membrane -v serve` in a subprocess; ``address`` is known once it listens."""

    def __init__(self, scene: str, bind: str = "tcp://127.0.0.1:*", *options: str) -> None:
        self.process = subprocess.Popen(
            [*MEMBRANE, "-v", "serve", "--scene", scene, "--bind", bind, *options],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.process.stdout is not None and self.process.stderr is not None
        self.stdout = LineReader(self.process.stdout)
        self.stderr = LineReader(self.process.stderr)
        line = self.stdout.wait_for("membrane serve: listening on ")
        self.address = line.split("listening on ", 1)[1].split()[0]

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(10)


def free_port_run(count: int) -> int:
    """A loopback port with the ``count - 1`` after it free now (``serve --workers``)."""
    for _ in range(50):
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            base = int(probe.getsockname()[1])
        if base + count > 65535:
            continue
        try:
            for port in range(base, base + count):
                with socket.socket() as taken:
                    taken.bind(("127.0.0.1", port))
        except OSError:
            continue
        return base
    raise AssertionError("no free run of ports")
