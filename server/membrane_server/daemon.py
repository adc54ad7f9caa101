"""Running the server as a Unix daemon: detach, hold a pidfile, log to a file.

Detaching (double fork, new session, closed descriptors, umask) is python-daemon's job (PEP 3143);
this module adds the pidfile policy: the lock is taken *before* detaching, so a second start on
the same pidfile fails in the user's terminal with a one-line error, and it is held by an
``flock`` for the daemon's whole life, so a stale file left by a killed process never blocks a
new start. The pidfile is removed on exit.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import IO

__all__ = ["AlreadyRunning", "PidFile", "run_detached"]

log = logging.getLogger(__name__)


class AlreadyRunning(RuntimeError):
    """Another live process holds the pidfile."""


class PidFile:
    """An exclusive, flock-held pidfile.

    ``acquire()`` locks it (or raises ``AlreadyRunning``); ``write_pid()`` records the current
    process (call it again after forking); ``release()`` removes it. Usable as a context manager.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path).resolve()
        self._handle: IO[str] | None = None

    def acquire(self) -> None:
        """Take the lock; raise ``AlreadyRunning`` when another process holds it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = self.path.open("a+")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise AlreadyRunning(
                f"a server already runs with pidfile {self.path} (pid {holder})"
            ) from None
        self._handle = handle
        self.write_pid()

    def write_pid(self) -> None:
        """Record this process's pid in the locked file."""
        if self._handle is None:
            raise RuntimeError("pidfile not acquired")
        self._handle.seek(0)
        self._handle.truncate()
        self._handle.write(f"{os.getpid()}\n")
        self._handle.flush()

    def fileno(self) -> int:
        """The locked descriptor (to keep open across detaching)."""
        if self._handle is None:
            raise RuntimeError("pidfile not acquired")
        return self._handle.fileno()

    def release(self) -> None:
        """Remove the file and drop the lock (idempotent)."""
        if self._handle is None:
            return
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        self._handle.close()
        self._handle = None

    def __enter__(self) -> PidFile:
        self.acquire()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()


def run_detached(main: Callable[[], int], pidfile: str | Path, logfile: str | Path | None) -> int:
    """Detach from the terminal and run ``main`` as a daemon holding ``pidfile``.

    Only the daemon returns from here (with ``main``'s exit code); the launching process exits
    0 inside python-daemon once the daemon is detached. Raises ``AlreadyRunning`` before
    detaching when the pidfile is held. ``main`` must create its ZeroMQ context and inference
    sessions itself: neither survives a fork.
    """
    import daemon  # the `server` extra

    lock = PidFile(pidfile)
    lock.acquire()
    log_path = Path(logfile).resolve() if logfile else Path(os.devnull)
    log_stream = log_path.open("a", buffering=1)
    context = daemon.DaemonContext(
        working_directory="/",
        umask=0o022,
        files_preserve=[lock.fileno(), log_stream.fileno()],
        stdout=log_stream,
        stderr=log_stream,
        signal_map={},  # the server installs its own SIGTERM/SIGINT/SIGHUP handlers
    )
    with context:
        lock.write_pid()
        _log_to(log_stream)
        try:
            return main()
        finally:
            lock.release()


def _log_to(stream: IO[str]) -> None:
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    if root.level == logging.NOTSET or root.level > logging.INFO:
        root.setLevel(logging.INFO)
