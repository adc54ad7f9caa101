"""`membrane serve --workers N`: N worker processes on consecutive ports, each a whole server.

One server process answers one request at a time in one Python thread, so more sessions than a
core can step need more processes. Each worker is `membrane serve` itself on its own endpoint,
holding its own sessions (a session's state never leaves its worker); clients choose the worker
a session belongs to by hashing its id over the workers' endpoints (``membrane_client.workers``),
which every worker's ``hello`` lists. This process only starts them, says where they listen,
passes SIGTERM and SIGINT on, and reports a worker that dies; the others go on serving (a dead
worker's sessions are lost; it is not restarted, so that no client's view of the list changes
under it).
"""

from __future__ import annotations

import logging
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from types import FrameType

from membrane_errors import UserError

__all__ = ["run_workers", "worker_endpoints"]

logger = logging.getLogger(__name__)

_TCP = re.compile(r"^tcp://(?P<host>[^:]+|\[[^\]]+\]):(?P<port>\d+)$")


def worker_endpoints(bind: str, count: int) -> list[str]:
    """``count`` endpoints from ``bind``: its port and the ``count - 1`` after it."""
    matched = _TCP.match(bind)
    if matched is None or int(matched["port"]) == 0:
        raise UserError(
            f"--workers needs a tcp:// endpoint with a fixed port (the workers take it and the "
            f"{count - 1} after it), got {bind!r}"
        )
    port = int(matched["port"])
    if port + count - 1 > 65535:
        raise UserError(f"--workers {count} from port {port} passes 65535")
    return [f"tcp://{matched['host']}:{port + i}" for i in range(count)]


def run_workers(
    serve_argv: Sequence[str],
    endpoints: Sequence[str],
    advertised: Sequence[str],
    notify_ready: Callable[[str], None] | None = None,
) -> int:
    """Start one `membrane serve` per endpoint (``serve_argv``: its options but ``--bind``),
    each told the ``advertised`` list (what clients reach them by, for ``hello``); print one
    line once all listen (and call ``notify_ready`` with the endpoints: a daemon's launcher
    returns then), and wait for them. Exit code 0 when they stopped on a signal, 1 when one
    failed to start."""
    listed = ",".join(advertised)
    workers = [_start(serve_argv, endpoint, listed) for endpoint in endpoints]
    stopping = threading.Event()

    def forward(signum: int, _frame: FrameType | None) -> None:
        stopping.set()
        for worker in workers:
            if worker.poll() is None:
                worker.send_signal(signum)

    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, forward)
    if not _all_listening(workers, stopping):
        forward(signal.SIGTERM, None)
        for worker in workers:
            worker.wait()
        return 1
    where = ", ".join(f"{e} (pid {w.pid})" for e, w in zip(endpoints, workers, strict=True))
    print(f"membrane serve: {len(workers)} workers listening on {where}", flush=True)
    if notify_ready is not None:
        notify_ready(",".join(endpoints))
    for worker, endpoint in zip(workers, endpoints, strict=True):
        threading.Thread(target=_relay, args=(worker,), daemon=True).start()
        threading.Thread(target=_watch, args=(worker, endpoint, stopping), daemon=True).start()
    for worker in workers:
        worker.wait()
    print("membrane serve: stopped", file=sys.stderr, flush=True)
    return 0


def _start(serve_argv: Sequence[str], endpoint: str, listed: str) -> subprocess.Popen[str]:
    command = [sys.executable, "-m", "membrane_cli", "serve", *serve_argv, "--bind", endpoint]
    return subprocess.Popen([*command, "--worker-list", listed], stdout=subprocess.PIPE, text=True)


def _all_listening(workers: Sequence[subprocess.Popen[str]], stopping: threading.Event) -> bool:
    """Each worker's first line is its "listening on" (or it exits having said why)."""
    for worker in workers:
        assert worker.stdout is not None
        line = worker.stdout.readline()
        if "listening on" not in line or stopping.is_set():
            return False
    return True


def _relay(worker: subprocess.Popen[str]) -> None:
    assert worker.stdout is not None
    for line in worker.stdout:
        print(line, end="", flush=True)


def _watch(worker: subprocess.Popen[str], endpoint: str, stopping: threading.Event) -> None:
    code = worker.wait()
    if not stopping.is_set():
        how = f"signal {-code}" if code < 0 else f"exit code {code}"
        logger.error("worker %s (pid %d) died (%s): its sessions are lost; the others go on",
                     endpoint, worker.pid, how)  # fmt: skip
