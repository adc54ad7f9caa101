"""`membrane serve --daemon`: detach, pidfile, refusing a second start, SIGHUP reload, SIGTERM."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

MEMBRANE = [sys.executable, "-m", "membrane_cli"]


def free_address() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{sock.getsockname()[1]}"


def membrane(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*MEMBRANE, *args], capture_output=True, text=True, timeout=timeout)


def wait_gone(pid: int, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


@pytest.fixture
def daemon_files(tmp_path: Path) -> tuple[Path, Path]:
    return tmp_path / "membrane.pid", tmp_path / "membrane.log"


@pytest.mark.slow
def test_daemon_lifecycle(daemon_files: tuple[Path, Path]) -> None:
    pidfile, logfile = daemon_files
    address = free_address()
    started = membrane(
        "serve", "--daemon", "--bind", address, "--pidfile", str(pidfile), "--logfile", str(logfile)
    )
    assert started.returncode == 0, started.stderr
    pid = int(pidfile.read_text())
    try:
        # Ready when the launcher returns: no polling needed.
        assert membrane("ping", "--connect", address, "--timeout", "2").returncode == 0

        second = membrane("serve", "--daemon", "--bind", free_address(), "--pidfile", str(pidfile))
        assert second.returncode == 2
        assert "already runs" in second.stderr and len(second.stderr.strip().splitlines()) == 1
        assert int(pidfile.read_text()) == pid, "a refused start must leave the pidfile alone"

        os.kill(pid, signal.SIGHUP)
        deadline = time.monotonic() + 20
        while "reloaded scenes" not in logfile.read_text() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert "reloaded scenes" in logfile.read_text()
        assert membrane("ping", "--connect", address, "--timeout", "2").returncode == 0
    finally:
        os.kill(pid, signal.SIGTERM)
    assert wait_gone(pid), "SIGTERM did not stop the daemon"
    assert not pidfile.exists(), "the pidfile must be removed on exit"
    assert "stopped after" in logfile.read_text()
    assert membrane("ping", "--connect", address, "--timeout", "0.3").returncode == 1


@pytest.mark.slow
def test_stale_pidfile_does_not_block(daemon_files: tuple[Path, Path]) -> None:
    pidfile, _ = daemon_files
    pidfile.write_text("999999\n")  # left by a process that died without cleaning up
    address = free_address()
    started = membrane("serve", "--daemon", "--bind", address, "--pidfile", str(pidfile))
    assert started.returncode == 0, started.stderr
    pid = int(pidfile.read_text())
    assert pid != 999999
    os.kill(pid, signal.SIGTERM)
    assert wait_gone(pid)
    assert not pidfile.exists()


@pytest.mark.slow
def test_daemon_that_cannot_bind_reports_failure(daemon_files: tuple[Path, Path]) -> None:
    pidfile, logfile = daemon_files
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        address = f"tcp://127.0.0.1:{taken.getsockname()[1]}"
        result = membrane(
            "serve", "--daemon", "--bind", address, "--pidfile", str(pidfile),
            "--logfile", str(logfile),
        )  # fmt: skip
    assert result.returncode == 1
    assert "failed to start" in result.stderr
    deadline = time.monotonic() + 10
    while pidfile.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not pidfile.exists()


@pytest.mark.slow
def test_pidfile_without_daemon_is_a_usage_error(tmp_path: Path) -> None:
    result = membrane("serve", "--pidfile", str(tmp_path / "x.pid"))
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1
