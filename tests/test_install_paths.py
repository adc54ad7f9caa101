"""Install paths, proven in fresh virtual environments.

- The container's path: exactly the Dockerfile's pip command (the ``server`` extra): torch must not
  be importable, and the server must start on a built-in scene and answer.
- The simulator's path: the project with no extras (pyzmq, msgpack, numpy) imports
  ``membrane_client`` and runs ``membrane query`` and ``membrane ping``; commands needing an extra
  say which one in one line.

These build the project's wheel and install from pip's cache, so they take tens of seconds each.
"""

from __future__ import annotations

import json
import re
import shlex
import socket
import subprocess
import time
import venv
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / "docker" / "Dockerfile"
INSTALL_TIMEOUT_S = 600


def dockerfile_install_command() -> list[str]:
    """The Dockerfile's `RUN ... pip install ...` command, without RUN and its --mount flags."""
    for line in DOCKERFILE.read_text().splitlines():
        if line.startswith("RUN ") and "pip install" in line:
            words = shlex.split(line[len("RUN ") :])
            return [w for w in words if not w.startswith("--mount=")]
    raise AssertionError("the Dockerfile has no RUN pip install line")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def make_venv(path: Path) -> Path:
    venv.EnvBuilder(with_pip=True, clear=True).create(path)
    return path / "bin"


def run(args: list[str], cwd: Path = ROOT, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def server_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bin_dir = make_venv(tmp_path_factory.mktemp("server-venv") / "venv")
    command = dockerfile_install_command()
    assert command[:4] == ["python", "-m", "pip", "install"], command
    result = run([str(bin_dir / "python"), *command[1:]], timeout=INSTALL_TIMEOUT_S)
    assert result.returncode == 0, result.stderr[-2000:]
    return bin_dir


@pytest.fixture(scope="module")
def client_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bin_dir = make_venv(tmp_path_factory.mktemp("client-venv") / "venv")
    result = run([str(bin_dir / "python"), "-m", "pip", "install", "."], timeout=INSTALL_TIMEOUT_S)
    assert result.returncode == 0, result.stderr[-2000:]
    return bin_dir


@pytest.fixture(scope="module")
def server_address(server_venv: Path) -> Iterator[str]:
    """A server started from the server-only venv on the built-in `membrane` scene."""
    address = f"tcp://127.0.0.1:{free_port()}"
    process = subprocess.Popen(
        [str(server_venv / "membrane"), "serve", "--scene", "membrane", "--bind", address],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        ping_command = [str(server_venv / "membrane"), "ping", "--connect", address]
        while time.monotonic() < deadline:
            ping = run(ping_command)
            if ping.returncode == 0:
                break
            assert process.poll() is None, process.stderr.read() if process.stderr else ""
        else:
            pytest.fail("the server did not answer within 60 s")
        yield address
    finally:
        process.terminate()
        process.wait(timeout=10)


def test_server_install_has_no_torch(server_venv: Path) -> None:
    result = run([str(server_venv / "python"), "-c", "import torch"])
    assert result.returncode != 0
    assert "No module named 'torch'" in result.stderr


def test_server_install_serves_a_query(server_venv: Path, server_address: str) -> None:
    membrane = str(server_venv / "membrane")
    result = run([membrane, "query", "--connect", server_address, "--t", "0.5", "--json"])
    assert result.returncode == 0, result.stderr
    frame = json.loads(result.stdout)
    assert frame["step"] == 50 and frame["t"] == 0.5
    assert len(frame["z"]) == 20 and all(len(row) == 20 for row in frame["z"])
    assert 1e-5 < frame["max_abs_z"] < 1e-3


def test_client_only_install_imports_no_server_deps(client_venv: Path) -> None:
    code = (
        "import sys, membrane_client\n"
        "heavy = {'onnxruntime', 'torch', 'pydantic', 'scipy'} & set(sys.modules)\n"
        "assert not heavy, heavy\n"
        "print('ok')"
    )
    result = run([str(client_venv / "python"), "-c", code])
    assert result.returncode == 0, result.stderr
    for module in ("onnxruntime", "torch", "pydantic", "scipy"):
        probe = run([str(client_venv / "python"), "-c", f"import {module}"])
        assert probe.returncode != 0, f"{module} should not be installed by the core deps"


def test_client_only_install_queries_and_pings(client_venv: Path, server_address: str) -> None:
    membrane = str(client_venv / "membrane")
    assert run([membrane, "ping", "--connect", server_address, "--timeout", "2"]).returncode == 0
    query = run([membrane, "query", "--connect", server_address, "--t", "0.25"])
    assert query.returncode == 0, query.stderr
    assert "step 25, t = 0.25 s" in query.stdout


def test_client_only_ping_fails_cleanly_without_server(client_venv: Path) -> None:
    address = f"tcp://127.0.0.1:{free_port()}"
    result = run([str(client_venv / "membrane"), "ping", "--connect", address, "--timeout", "0.3"])
    assert result.returncode == 1
    assert len(result.stderr.strip().splitlines()) <= 1


@pytest.mark.parametrize("command", [["serve"], ["train", "string-forced", "--out", "x"]])
def test_client_only_commands_name_their_extra(client_venv: Path, command: list[str]) -> None:
    result = run([str(client_venv / "membrane"), *command])
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert re.search(r"pip install 'membrane\[(server|train)\]'", lines[0]), lines[0]


def test_client_with_bench_extra_runs_the_load_tester(
    client_venv: Path, server_address: str
) -> None:
    membrane = str(client_venv / "membrane")
    without = run([membrane, "bench", "--connect", server_address, "--duration", "1"])
    assert without.returncode == 2
    assert "pip install 'membrane[bench]'" in without.stderr
    install = run(
        [str(client_venv / "python"), "-m", "pip", "install", ".[bench]"], timeout=INSTALL_TIMEOUT_S
    )
    assert install.returncode == 0, install.stderr[-2000:]
    bench = run(
        [membrane, "bench", "--connect", server_address, "--rate", "200", "--duration", "1",
         "--warmup", "0.2", "--json"],
    )  # fmt: skip
    assert bench.returncode == 0, bench.stderr[-2000:]
    assert "p99" in bench.stdout
