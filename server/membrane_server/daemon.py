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
import select
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import IO

from membrane_errors import UserError

__all__ = ["AlreadyRunning", "PidFile", "run_detached"]

log = logging.getLogger(__name__)


class AlreadyRunning(UserError):
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

    def detach(self) -> None:
        """Close this process's handle without removing the file (another process holds it)."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None

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


def run_detached(
    main: Callable[[Callable[[str], None]], int],
    pidfile: str | Path | None,
    logfile: str | Path | None,
    ready_timeout: float = 120.0,
) -> int:
    """Run ``main(notify_ready)`` as a detached daemon; return in the launching process.

    The launcher takes the pidfile lock (raising ``AlreadyRunning`` at once if it is held),
    forks, and waits until the daemon calls ``notify_ready(address)`` once it serves, or fails.
    So "the command returned 0" means "the server answers": scripts can `membrane ping` right
    after. The launcher returns 0 when the daemon is ready and 1 when it failed to start (its
    reason, from the daemon or the log file, is logged). The daemon itself never returns from
    here: it exits with ``main``'s code. ``main`` must create its ZeroMQ context and inference
    sessions itself, since neither survives a fork.
    """
    lock = PidFile(pidfile) if pidfile else None
    if lock is not None:
        lock.acquire()
    read_end, write_end = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover - runs in the daemon, outside coverage's process
        os.close(read_end)
        os._exit(_daemon_main(main, lock, logfile, write_end))
    os.close(write_end)
    if lock is not None:
        lock.detach()  # the daemon holds the lock now; the launcher must not remove the file
    try:
        return _await_ready(read_end, ready_timeout, logfile)
    finally:
        os.close(read_end)
        os.waitpid(child, 0)  # the intermediate process exits as soon as the daemon detaches


def _await_ready(read_end: int, timeout: float, logfile: str | Path | None) -> int:
    where = f" (see {logfile})" if logfile else ""
    ready, _, _ = select.select([read_end], [], [], timeout)
    if not ready:
        log.error("the daemon did not report ready within %.0f s%s", timeout, where)
        return 1
    message = os.read(read_end, 4096).decode(errors="replace").strip()
    status, _, detail = message.partition(" ")
    if status == "ready":
        log.info("daemon serving on %s", detail)
        return 0
    log.error("the daemon failed to start: %s%s", detail or "it exited", where)
    return 1


def _daemon_main(
    main: Callable[[Callable[[str], None]], int],
    lock: PidFile | None,
    logfile: str | Path | None,
    notify_fd: int,
) -> int:
    import daemon  # the `server` extra

    log_path = Path(logfile).resolve() if logfile else Path(os.devnull)
    log_stream = log_path.open("a", buffering=1)
    keep = [log_stream.fileno(), notify_fd] + ([lock.fileno()] if lock is not None else [])
    context = daemon.DaemonContext(
        working_directory="/",
        umask=0o022,
        files_preserve=keep,
        stdout=log_stream,
        stderr=log_stream,
        signal_map={},  # the server installs its own SIGTERM/SIGINT/SIGHUP handlers
    )
    with context:
        if lock is not None:
            lock.write_pid()
        _log_to(log_stream)

        notifier = _Notifier(notify_fd)
        code = 1
        try:
            code = main(lambda address: notifier.send(f"ready {address}"))
        except Exception as exc:
            log.exception("the server failed")
            notifier.send(f"error {' '.join(str(exc).split())}")
        finally:
            notifier.send(f"error the server exited with code {code}")  # no-op once ready
            if lock is not None:
                lock.release()
        return code


class _Notifier:
    """Sends one line to the launcher, once: the descriptor is closed right after."""

    def __init__(self, fd: int) -> None:
        self._fd: int | None = fd

    def send(self, message: str) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            os.write(fd, (message + "\n").encode())
        except OSError:  # the launcher is gone: nobody to tell
            pass
        finally:
            os.close(fd)


def _plain_log_to(stream: IO[str]) -> None:
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)


def _log_to(stream: IO[str]) -> None:
    """Log to the daemon's file through a handler that never blocks the serving thread and
    cannot flood the file (``log_output``)."""
    from membrane_server.log_output import LOG_FORMAT, install

    output = install(stream, replace_all=True)  # a log file has a descriptor
    if output is not None:
        output.setFormatter(logging.Formatter(LOG_FORMAT))  # the file's format, always
    else:  # no descriptor: logging as before, blocking
        _plain_log_to(stream)
    root = logging.getLogger()
    if root.level == logging.NOTSET or root.level > logging.INFO:
        root.setLevel(logging.INFO)
