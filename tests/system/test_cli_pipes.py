"""Every `membrane` command that writes to stdout ends quietly when its reader goes away.

Each command runs as a real process whose stdout is a real pipe, read by this test and closed:

- at once, before the command wrote anything (``membrane stats | true``): its first write, or the
  final flush of what it buffered, meets a pipe without a reader;
- after 10 bytes (``membrane query --t 0.5 --json | head -c 10``), with the pipe's capacity cut
  to one page and the child's output unbuffered (PYTHONUNBUFFERED), so that what follows the
  first 10 bytes meets the closed pipe: deterministic for outputs longer than the pipe holds
  (``query --json``: 9 kB), and for the others whenever their writes come after the close.

Either way the command must exit 0 (docs/OPERATIONS.md, "Exit codes, pipes and the version"), with
nothing on stderr but what it writes there by design (``tradeoff``'s progress lines). The
server, the CoppeliaSim stand-in and every file a command writes live on loopback or in a
temporary folder. Not here: `serve`, `view` and `coppelia` against a real CoppeliaSim are
long-running (serve's case is the last test), `animate` writes to stderr only, and `train` and
`export` take minutes.
"""

from __future__ import annotations

import fcntl
import os
import re
import select
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from membrane_client import Client
from membrane_server.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

RUN_TIMEOUT_S = 60.0
READ_BYTES = 10
PIPE_CAPACITY = 4096  # one page, the smallest a Linux pipe can be

# What each command is run as; {server}, {sim} and {tmp} are filled in per test.
COMMANDS: dict[str, str] = {
    "help": "--help",
    "version": "--version",
    "query-help": "query --help",
    "query": "query --connect {server} --t 0.5",
    "query-json": "query --connect {server} --t 0.5 --json",
    "query-float64-json": "query --connect {server} --t 0.5 --json --float64",
    "ping": "ping --connect {server}",
    "stats": "stats --connect {server}",
    "stats-json": "stats --connect {server} --json",
    "keys": "keys {tmp}/keys robot",
    "exact": "exact membrane-forced --nx 11 --ny 11 --nt 11 --out {tmp}/ref.npz",
    "data": (
        "data koopman-string --out {tmp}/data --train 1 --validation 1 --test 1 --steps 10 "
        "--families sine --no-progress"
    ),
    "evaluate-json": "evaluate membrane-forced --json",
    "bench": "bench --connect {server} --rate 200 --duration 0.2 --warmup 0 --quiet",
    "bench-json": "bench --connect {server} --rate 200 --duration 0.2 --warmup 0 --quiet --json",
    "bench-clients-json": (
        "bench --connect {server} --rate 200 --duration 0.2 --warmup 0 --clients 2 --quiet --json"
    ),
    "tradeoff": "tradeoff --quick --scene membrane --no-plot --rounds 2 --out {tmp}/tradeoff.md",
    "coppelia": "coppelia --connect {server} --sim-port {sim} --steps 5",
}

# What a command writes to stderr by design, line by line (anything else fails the test).
BY_DESIGN_STDERR: dict[str, re.Pattern[str]] = {
    "tradeoff": re.compile(r"\[\d+/\d+\] .*"),
}


def membrane_command() -> list[str]:
    """The installed `membrane` script beside this interpreter, or the module it runs."""
    script = Path(sys.executable).with_name("membrane")
    return [str(script)] if script.exists() else [sys.executable, "-m", "membrane_cli"]


@pytest.fixture(scope="module")
def standin() -> Iterator[Any]:
    """A CoppeliaSim stand-in on a free loopback port, at the membrane scene's dt (so that the
    adapter has no time step to change and nothing to warn about)."""
    from membrane_coppelia.standin import CoppeliaStandin  # the dev extra has it: never a skip

    with CoppeliaStandin(dt=0.01) as sim:
        yield sim


def small_pipe() -> tuple[int, int]:
    read_end, write_end = os.pipe()
    if hasattr(fcntl, "F_SETPIPE_SZ"):  # Linux
        fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, PIPE_CAPACITY)
    return read_end, write_end


def read_some(fd: int, count: int, timeout: float) -> bytes:
    """Up to ``count`` bytes from ``fd``: fewer only at end of file or after ``timeout``."""
    deadline = time.monotonic() + timeout
    data = b""
    while len(data) < count:
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            break
        chunk = os.read(fd, count - len(data))
        if not chunk:
            break
        data += chunk
    return data


def run_with_closed_stdout(
    argv: list[str], *, after: int, unbuffered: bool
) -> tuple[int, bytes, str]:
    """Run ``argv`` with stdout a pipe closed after reading ``after`` bytes; returns the exit
    code, what was read and stderr."""
    env = dict(os.environ)
    env.pop("PYTHONUNBUFFERED", None)
    if unbuffered:
        env["PYTHONUNBUFFERED"] = "1"
    read_end, write_end = small_pipe()
    try:
        process = subprocess.Popen(argv, stdout=write_end, stderr=subprocess.PIPE, env=env)
    finally:
        os.close(write_end)
    try:
        got = read_some(read_end, after, RUN_TIMEOUT_S) if after else b""
    finally:
        os.close(read_end)  # the reader goes away
    try:
        _, stderr = process.communicate(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        raise
    return process.returncode, got, stderr.decode(errors="replace")


def unexpected_stderr(name: str, stderr: str) -> list[str]:
    allowed = BY_DESIGN_STDERR.get(name)
    return [
        line
        for line in stderr.splitlines()
        if allowed is None or not allowed.fullmatch(line) or "Error" in line
    ]


@pytest.mark.parametrize("name", sorted(COMMANDS))
@pytest.mark.parametrize("when", ["at-once", "after-10-bytes"])
def test_a_command_whose_reader_leaves_exits_0_quietly(
    name: str,
    when: str,
    membrane_server: Server,
    tmp_path: Path,
    request: pytest.FixtureRequest,
) -> None:
    template = COMMANDS[name]
    sim = request.getfixturevalue("standin").port if "{sim}" in template else 0
    words = shlex.split(template.format(server=membrane_server.address, sim=sim, tmp=tmp_path))
    after = READ_BYTES if when == "after-10-bytes" else 0
    code, got, stderr = run_with_closed_stdout(
        [*membrane_command(), *words], after=after, unbuffered=bool(after)
    )
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr, stderr
    assert unexpected_stderr(name, stderr) == [], stderr
    assert code == 0, stderr
    assert len(got) == after, got  # the command did write, and the reader left after 10 bytes


def test_the_stderr_filter_lets_only_by_design_lines_through() -> None:
    progress = "[1/5] membrane 5x5 exact reference exact (-): p50 82 us"
    assert unexpected_stderr("tradeoff", progress) == []
    assert unexpected_stderr("tradeoff", "BrokenPipeError: [Errno 32]") != []
    assert unexpected_stderr("query", progress) == [progress]


def test_a_server_whose_reader_left_after_its_first_line_keeps_serving() -> None:
    """`membrane serve | head -1`: the reader takes the address and leaves; the server answers
    on, and stops on SIGTERM with exit code 0, its stderr free of tracebacks."""
    read_end, write_end = small_pipe()
    try:
        process = subprocess.Popen(
            [*membrane_command(), "serve", "--scene", "membrane", "--bind", "tcp://127.0.0.1:*"],
            stdout=write_end,
            stderr=subprocess.PIPE,
        )
    finally:
        os.close(write_end)
    try:
        line = b""
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while not line.endswith(b"\n") and time.monotonic() < deadline:
            chunk = read_some(read_end, 1, deadline - time.monotonic())
            if not chunk:
                break
            line += chunk
        os.close(read_end)
        read_end = -1
        match = re.search(rb"listening on (\S+)", line)
        assert match, line
        address = match.group(1).decode()
        assert address.startswith("tcp://127.0.0.1:"), address
        with Client(address, timeout=5.0) as client:
            assert client.ping() > 0
            assert client.query(0.5).step == 50
    finally:
        if read_end >= 0:
            os.close(read_end)
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
        try:
            _, stderr_bytes = process.communicate(timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.communicate()
            raise
    stderr = stderr_bytes.decode(errors="replace")
    assert "Traceback" not in stderr, stderr
    assert process.returncode == 0, stderr
    assert stderr.splitlines()[-1:] == ["membrane serve: stopped"], stderr
