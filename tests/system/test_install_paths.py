"""Install paths, proven in fresh virtual environments.

- The container's path: exactly the Dockerfile's pip command (the ``server`` extra): torch must not
  be importable, and the server must start on a built-in scene and answer.
- The simulator's path: the wheel ``make wheel`` builds (``pip wheel . --no-deps``), installed with
  no extras (pyzmq, msgpack, numpy) in a fresh venv, imports ``membrane_client`` and runs
  ``membrane query``, ``membrane ping`` and ``membrane stats`` against a real server; commands
  needing an extra say which one in one line, and that line's ``pip install`` works.
- The client's own tests: the same wheel, no extras, plus pytest, pytest-timeout and hypothesis
  (what tests/client needs, at this environment's versions), runs ``pytest tests/client``: the
  client's tests need nothing of the server's dependencies.

The server path installs onnxruntime and scipy (tens of seconds); the wheel path builds the wheel
and installs it with the test environment's pip into a venv without pip of its own (8 to 16 s
measured on a shared 2-core machine, pyzmq, msgpack and numpy fetched from the index), so its
tests are marked slow.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import socket
import subprocess
import sys
import time
import venv
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest

from membrane_server.server import Server

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "docker" / "Dockerfile"
COMPOSE = ROOT / "docker" / "compose.yaml"
INSTALL_TIMEOUT_S = 600
SERVER_SIDE_MODULES = ("onnxruntime", "torch", "pydantic", "scipy")
# What tests/client needs beyond the core install, pinned to this environment's versions.
CLIENT_TEST_TOOLS = ("pytest", "pytest-timeout", "hypothesis")


def dockerfile_install_command() -> list[str]:
    """The Dockerfile's `RUN ... pip install ...` command, without RUN and its --mount flags."""
    for line in DOCKERFILE.read_text().splitlines():
        if line.startswith("RUN ") and "pip install" in line:
            words = shlex.split(line[len("RUN ") :])
            return [w for w in words if not w.startswith("--mount=")]
    raise AssertionError("the Dockerfile has no RUN pip install line")


def compose_services() -> dict[str, dict[str, str]]:
    """compose.yaml's services and their keys, with the rest of each key's line (no YAML library
    in the project: the file keeps to two-space indentation and one key per line)."""
    services: dict[str, dict[str, str]] = {}
    current: dict[str, str] | None = None
    for line in COMPOSE.read_text().splitlines():
        if re.fullmatch(r"  [a-z][a-z0-9-]*:", line):
            current = services.setdefault(line.strip().rstrip(":"), {})
        elif current is not None and (key := re.match(r"    ([a-z_]+):(.*)", line)):
            current[key.group(1)] = key.group(2).strip()
    return services


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


def pip_into(venv_python: Path, *requirements: str) -> subprocess.CompletedProcess[str]:
    """This environment's pip installing into another venv (which then needs no pip of its own)."""
    command = [sys.executable, "-m", "pip", "--python", str(venv_python), "install", "-q"]
    return run([*command, *requirements], timeout=INSTALL_TIMEOUT_S)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The project's wheel, built as `make wheel` builds it."""
    out = tmp_path_factory.mktemp("wheel")
    command = [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(out)]
    result = run(command, timeout=INSTALL_TIMEOUT_S)
    assert result.returncode == 0, result.stderr[-2000:]
    (built,) = out.glob("*.whl")
    return built


@pytest.fixture(scope="module")
def client_venv(tmp_path_factory: pytest.TempPathFactory, wheel: Path) -> Path:
    """A fresh venv with the wheel installed, no extras."""
    root = tmp_path_factory.mktemp("client-venv") / "venv"
    venv.EnvBuilder(with_pip=False, clear=True).create(root)
    bin_dir = root / "bin"
    result = pip_into(bin_dir / "python", str(wheel))
    assert result.returncode == 0, result.stderr[-2000:]
    return bin_dir


@pytest.fixture(scope="module")
def client_tests_venv(tmp_path_factory: pytest.TempPathFactory, wheel: Path) -> Path:
    """A fresh venv with the wheel (no extras) and only the tools tests/client needs."""
    root = tmp_path_factory.mktemp("client-tests-venv") / "venv"
    venv.EnvBuilder(with_pip=False, clear=True).create(root)
    bin_dir = root / "bin"
    tools = [f"{name}=={metadata.version(name)}" for name in CLIENT_TEST_TOOLS]
    result = pip_into(bin_dir / "python", str(wheel), *tools)
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


def test_compose_builds_its_image_and_never_pulls_it() -> None:
    services = compose_services()
    assert set(services) == {"server", "demo-client"}
    for name, keys in services.items():
        if "build" in keys:
            assert keys.get("pull_policy") == "build", name  # a missing policy pulls first
        else:
            assert keys.get("pull_policy") == "never", name
            assert keys["image"] == services["server"]["image"], name  # the server's build


def test_compose_example_serves_a_scene_from_the_mounted_folder() -> None:
    text = COMPOSE.read_text()
    mount = re.search(r"#\s+- \./[\w-]+:(/[\w/]+):ro", text)
    command = re.search(r"#\s+command: (\[.*\])", text)
    assert mount is not None and command is not None, text
    words = json.loads(command.group(1))
    assert words[:2] == ["membrane", "serve"]
    assert words[words.index("--scene") + 1].startswith(mount.group(1) + "/")
    assert words[words.index("--bind") + 1] == "tcp://0.0.0.0:5555"  # reachable through the port


@pytest.mark.slow
def test_server_install_has_no_torch(server_venv: Path) -> None:
    result = run([str(server_venv / "python"), "-c", "import torch"])
    assert result.returncode != 0
    assert "No module named 'torch'" in result.stderr


@pytest.mark.slow
def test_server_install_builds_physical_tissue_without_torch(server_venv: Path) -> None:
    """scikit-fem and meshio come with the server extra; the fem room never needs torch."""
    script = (
        "import sys; from membrane_models import fem; "
        "s = fem.assemble(fem.rectangle(0.05, 0.05, 0.01), fem.Plate(1.5e6, 0.45, 0.003, 1109.0), "
        "'clamped'); print(f'{fem.modes(s, 1).frequency[0]:.1f}'); "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    result = run([str(server_venv / "python"), "-c", script])
    assert result.returncode == 0, result.stderr
    assert 70.0 < float(result.stdout) < 90.0  # Hz: the skin patch's first mode (81.7, fine)


@pytest.mark.slow
def test_server_install_serves_a_query(server_venv: Path, server_address: str) -> None:
    membrane = str(server_venv / "membrane")
    result = run([membrane, "query", "--connect", server_address, "--t", "0.5", "--json"])
    assert result.returncode == 0, result.stderr
    frame = json.loads(result.stdout)
    assert frame["step"] == 50 and frame["t"] == 0.5
    assert len(frame["z"]) == 20 and all(len(row) == 20 for row in frame["z"])
    assert 1e-5 < frame["max_abs_z"] < 1e-3


@pytest.mark.slow
def test_wheel_is_the_membrane_tissue_distribution(wheel: Path, client_venv: Path) -> None:
    assert wheel.name.startswith("membrane_tissue-"), wheel.name
    code = "from importlib import metadata; print(metadata.version('membrane-tissue'))"
    result = run([str(client_venv / "python"), "-c", code])
    assert result.returncode == 0, result.stderr


@pytest.mark.slow
def test_client_only_install_imports_no_server_deps(client_venv: Path) -> None:
    code = (
        "import sys, membrane_client\n"
        f"heavy = {set(SERVER_SIDE_MODULES)!r} & set(sys.modules)\n"
        "assert not heavy, heavy\n"
        "print('ok')"
    )
    result = run([str(client_venv / "python"), "-c", code])
    assert result.returncode == 0, result.stderr
    for module in SERVER_SIDE_MODULES:
        probe = run([str(client_venv / "python"), "-c", f"import {module}"])
        assert probe.returncode != 0, f"{module} should not be installed by the core deps"


@pytest.mark.slow
def test_client_tests_pass_on_a_client_only_install(client_tests_venv: Path) -> None:
    python = str(client_tests_venv / "python")
    for module in SERVER_SIDE_MODULES:  # the test tools brought none of them
        probe = run([python, "-c", f"import {module}"])
        assert probe.returncode != 0, f"{module} is installed next to the client's tests"
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    result = subprocess.run(
        [python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/client"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=INSTALL_TIMEOUT_S,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert re.search(r"^\d+ passed", result.stdout.splitlines()[-1]), result.stdout[-2000:]
    assert "skipped" not in result.stdout.splitlines()[-1], result.stdout[-2000:]


@pytest.mark.slow
def test_client_only_install_queries_and_pings(client_venv: Path, membrane_server: Server) -> None:
    membrane, address = str(client_venv / "membrane"), membrane_server.address
    ping = run([membrane, "ping", "--connect", address, "--timeout", "2"])
    assert ping.returncode == 0, ping.stderr
    assert ping.stdout.startswith(f"pong from {address}")
    query = run([membrane, "query", "--connect", address, "--t", "0.25"])
    assert query.returncode == 0, query.stderr
    assert "step 25, t = 0.25 s" in query.stdout
    stats = run([membrane, "stats", "--connect", address, "--json"])
    assert stats.returncode == 0, stats.stderr
    assert json.loads(stats.stdout)["requests"] >= 2


@pytest.mark.slow
def test_client_only_ping_fails_cleanly_without_server(client_venv: Path) -> None:
    address = f"tcp://127.0.0.1:{free_port()}"
    result = run([str(client_venv / "membrane"), "ping", "--connect", address, "--timeout", "0.3"])
    assert result.returncode == 1
    assert len(result.stderr.strip().splitlines()) <= 1


@pytest.mark.slow
@pytest.mark.parametrize("command", [["serve"], ["train", "string-forced", "--out", "x"]])
def test_client_only_commands_name_their_extra(client_venv: Path, command: list[str]) -> None:
    result = run([str(client_venv / "membrane"), *command])
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert re.search(r"pip install 'membrane-tissue\[(server|train)\]'", lines[0]), lines[0]


@pytest.mark.slow
def test_client_with_bench_extra_runs_the_load_tester(
    client_venv: Path, membrane_server: Server
) -> None:
    membrane, address = str(client_venv / "membrane"), membrane_server.address
    without = run([membrane, "bench", "--connect", address, "--duration", "1"])
    assert without.returncode == 2
    hint = re.search(r"pip install '(membrane-tissue\[bench\])'", without.stderr)
    assert hint is not None, without.stderr
    # The hint, run as printed: pip finds the installed distribution and adds the extra's deps.
    install = pip_into(client_venv / "python", hint.group(1))
    assert install.returncode == 0, install.stderr[-2000:]
    bench = run(
        [membrane, "bench", "--connect", address, "--rate", "200", "--duration", "1",
         "--warmup", "0.2", "--json"],
    )  # fmt: skip
    assert bench.returncode == 0, bench.stderr[-2000:]
    assert "p99" in bench.stdout
