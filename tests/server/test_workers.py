"""`membrane serve --workers N` and the client that hashes sessions over them: a session's
every step reaches its owner; a worker killed with SIGKILL loses exactly its own sessions
(their next step says unknown_session), the others' frames are an undisturbed run's bit for
bit, and a film poller has no failed query."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from serve_process import MEMBRANE, LineReader, free_port_run

from membrane_client import Client, ServerError
from membrane_client.protocol import ErrorCode
from membrane_client.session import Load
from membrane_client.workers import WorkerClient, owner
from membrane_errors import MembraneError, UserError
from membrane_server.workers import worker_endpoints

SESSIONS, BEFORE, AFTER = 30, 6, 6


def _ids(count: int) -> list[str]:
    return [f"session-{i:02d}" for i in range(count)]


def test_the_owner_is_stable_spread_and_moves_only_a_gone_workers_sessions() -> None:
    endpoints = [f"tcp://127.0.0.1:{5600 + i}" for i in range(3)]
    ids = _ids(3000)
    owners = {i: owner(i, endpoints) for i in ids}
    assert owners == {i: owner(i, list(reversed(endpoints))) for i in ids}  # order-free
    assert min(Counter(owners.values()).values()) > 900  # about a third each
    left = [e for e in endpoints if e != endpoints[1]]
    for i in ids:
        after = owner(i, left)
        assert after == owners[i] if owners[i] != endpoints[1] else after in left


def test_worker_endpoints_need_a_fixed_tcp_port() -> None:
    assert worker_endpoints("tcp://127.0.0.1:7000", 3) == [
        "tcp://127.0.0.1:7000", "tcp://127.0.0.1:7001", "tcp://127.0.0.1:7002"
    ]  # fmt: skip
    for bad in ("tcp://127.0.0.1:*", "tcp://127.0.0.1:0", "ipc:///tmp/m", "tcp://h:65535"):
        with pytest.raises(UserError, match="--workers"):
            worker_endpoints(bad, 3)


class Workers:
    """`membrane serve --workers 3` in a subprocess; ``pids`` per endpoint once they listen."""

    def __init__(self, count: int) -> None:
        base = free_port_run(count)
        self.process = subprocess.Popen(
            [*MEMBRANE, "serve", "--workers", str(count), "--bind", f"tcp://127.0.0.1:{base}",
             "--scene", "membrane-live", "--scene", "membrane",
             # one client holds every session: the hash may give one worker more than 16 of them
             "--max-sessions-per-peer", str(SESSIONS)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.process.stdout is not None and self.process.stderr is not None
        self.stdout, self.stderr = LineReader(self.process.stdout), LineReader(self.process.stderr)
        line = self.stdout.wait_for("membrane serve: ", timeout=120)
        self.pids = {e: int(p) for e, p in re.findall(r"(tcp://\S+) \(pid (\d+)\)", line)}
        assert len(self.pids) == count, line

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                self.process.kill()
        for pid in self.pids.values():  # any worker left behind
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def workers() -> Iterator[Workers]:
    started = Workers(3)
    yield started
    started.close()


def _load(index: int, k: int) -> list[Load]:
    """Each session's own input: a load at its own place, switched on and off."""
    at = (0.2 + 0.02 * index, 0.3 + 0.01 * index)
    return [Load(at, -0.5 if (k // 3) % 2 == 0 else 0.0, 0.05)]


@pytest.mark.slow
def test_a_killed_worker_loses_only_its_sessions_and_films_go_on(workers: Workers) -> None:
    cluster = WorkerClient(next(iter(workers.pids)), timeout=0.5)
    assert set(cluster.endpoints) == set(workers.pids)  # hello listed every worker
    sessions = [cluster.session("membrane-live", session_id=i) for i in _ids(SESSIONS)]
    failed_queries = 0

    def poll_film(t: float) -> None:
        nonlocal failed_queries
        try:
            assert cluster.query(t, "membrane").z.shape == (20, 20)
        except (MembraneError, AssertionError):  # counted: the poller must never fail
            failed_queries += 1

    for k in range(BEFORE):
        for index, session in enumerate(sessions):
            session.step(loads=_load(index, k), frame=False)
        poll_film(0.01 * k)
    victim = sessions[0].endpoint
    os.kill(workers.pids[victim], signal.SIGKILL)
    lost: set[str] = set()
    frames: dict[str, np.ndarray] = {}
    for k in range(BEFORE, BEFORE + AFTER):
        for index, session in enumerate(sessions):
            if session.id in lost:
                continue
            try:
                z = session.step(loads=_load(index, k), frame=True).z
                assert z is not None
                frames[session.id] = z
            except ServerError as exc:
                assert exc.code == ErrorCode.UNKNOWN_SESSION, exc
                lost.add(session.id)
        poll_film(0.01 * k)
    expected_lost = {s.id for s in sessions if owner(s.id, list(workers.pids)) == victim}
    assert lost == expected_lost and 0 < len(lost) < SESSIONS
    assert failed_queries == 0
    assert victim not in cluster.alive
    # The survivors' frames equal an undisturbed run's (one server, the same inputs).
    alone = next(e for e in workers.pids if e != victim)
    with Client(alone, timeout=5.0) as reference:
        for index, session_id in enumerate(_ids(SESSIONS)):
            if session_id in lost:
                continue
            with reference.session("membrane-live") as undisturbed:
                for k in range(BEFORE + AFTER):
                    z = undisturbed.step(loads=_load(index, k), frame=True).z
            assert z is not None and np.array_equal(z, frames[session_id]), session_id
    cluster.close()


@pytest.mark.slow
def test_reopen_opens_a_lost_session_on_its_new_owner(workers: Workers) -> None:
    cluster = WorkerClient(list(workers.pids), timeout=0.5)
    session = cluster.session("membrane-live", session_id="reopened", reopen=True)
    for _ in range(3):
        session.step(frame=False)
    first = session.endpoint
    os.kill(workers.pids[first], signal.SIGKILL)
    frame = session.step(frame=True)
    assert session.endpoint != first and session.reopened == 1 and frame.k == 1
    cluster.close()


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--workers", "3", "--bind", "tcp://127.0.0.1:*"], "needs a tcp:// endpoint with a fixed"),
        (["--workers", "0"], "must be in 1..256"),
        (["--workers", "2", "--bind", "tcp://127.0.0.1:7000", "--worker-list", "tcp://a:1"],
         "--worker-list names 1 workers, --workers 2"),
        (["--worker-list", "nope"], "--worker-list needs a ZeroMQ endpoint"),
    ],
)  # fmt: skip
def test_bad_worker_options_are_one_line_and_exit_2(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from membrane_cli.dispatcher import main

    code: object
    try:
        code = main(["serve", *argv])
    except SystemExit as exc:  # argparse's own refusal of a value
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1, err


def test_hello_lists_the_workers_a_server_is_told_of() -> None:
    from membrane_server.server import Server

    listed = ("tcp://membrane-0.membrane:5555", "tcp://membrane-1.membrane:5555")
    server = Server(["membrane"], bind="tcp://127.0.0.1:*", workers=listed)
    server.start()
    try:
        with Client(server.address) as client:
            assert client.hello().workers == listed
    finally:
        server.stop()
    alone = Server(["membrane"], bind="tcp://127.0.0.1:*")
    alone.start()
    try:
        with Client(alone.address) as client:
            assert client.hello().workers == () and "workers" not in client.request("hello")
    finally:
        alone.stop()


@pytest.mark.slow
def test_workers_run_as_one_daemon_that_sigterm_stops_whole(tmp_path: Path) -> None:
    pidfile, logfile = tmp_path / "membrane.pid", tmp_path / "membrane.log"
    base = free_port_run(2)
    endpoints = worker_endpoints(f"tcp://127.0.0.1:{base}", 2)
    started = subprocess.run(
        [*MEMBRANE, "serve", "--workers", "2", "--bind", endpoints[0], "--daemon",
         "--pidfile", str(pidfile), "--logfile", str(logfile), "--scene", "membrane"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert started.returncode == 0, started.stderr
    pid = int(pidfile.read_text())
    log = ""
    try:
        for endpoint in endpoints:  # ready when the launcher returned: both answer
            with Client(endpoint, timeout=5.0) as client:
                assert client.hello().workers == tuple(endpoints)
        log = logfile.read_text()
        pids = [int(p) for p in re.findall(r"\(pid (\d+)\)", log)]
        assert len(pids) == 2 and pid not in pids, log
        os.kill(pid, signal.SIGTERM)
        for child in [pid, *pids]:
            assert _gone(child), f"pid {child} still runs after SIGTERM to the daemon"
        assert not pidfile.exists()
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        for child in re.findall(r"\(pid (\d+)\)", log):
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(child), signal.SIGKILL)


def _gone(pid: int, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False
