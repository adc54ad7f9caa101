"""Safe defaults: CurveZMQ authentication, loopback binds, no pickle, enforced limits.

CurveZMQ servers here run on a ZeroMQ context of their own (the authenticator's ZAP handler
belongs to a context), bound to 127.0.0.1 on a free port.
"""

from __future__ import annotations

import argparse
import inspect
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import zmq
import zmq.auth

from membrane_client import Client, Timeout
from membrane_client.client import DEFAULT_ADDRESS
from membrane_client.curve import CurveError, client_socket_options
from membrane_client.protocol import MAX_LATTICE_POINTS, MAX_REPLY_BYTES, encode, ok_reply
from membrane_server.cli import add_serve
from membrane_server.scene import DEFAULT_TABLE_MAX_BYTES, SceneError, scene_from_dict
from membrane_server.security import (
    CurveAuthenticator,
    is_loopback_endpoint,
    server_socket_options,
)
from membrane_server.served import ServedScene
from membrane_server.server import Server

if TYPE_CHECKING:
    from onnx_graphs import TestModel

MEMBRANE = [sys.executable, "-m", "membrane_cli"]
REPO = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Keys:
    """Certificates made with zmq.auth.create_certificates, and the allowed-clients folder."""

    server_public: Path
    server_secret: Path
    client_secret: Path
    stranger_secret: Path  # a valid key pair the server does not know
    impostor_public: Path  # another server's public key
    allowed: Path


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> Keys:
    root = tmp_path_factory.mktemp("keys")
    made = {}
    for name in ("server", "client", "stranger", "impostor"):
        folder = root / name
        folder.mkdir()
        made[name] = zmq.auth.create_certificates(folder, name)  # (public, secret) paths
    allowed = root / "allowed"
    allowed.mkdir()
    shutil.copy(made["client"][0], allowed)
    return Keys(
        server_public=Path(made["server"][0]),
        server_secret=Path(made["server"][1]),
        client_secret=Path(made["client"][1]),
        stranger_secret=Path(made["stranger"][1]),
        impostor_public=Path(made["impostor"][0]),
        allowed=allowed,
    )


@pytest.fixture(scope="module")
def small_scene() -> ServedScene:
    scene = scene_from_dict(
        {"name": "small", "model": "string-forced", "evaluator": "exact", "lattice": {"nx": 9},
         "dt": 0.01, "duration": 1.0}
    )  # fmt: skip
    return ServedScene.load(scene)


@pytest.fixture(scope="module")
def curve_server(keys: Keys, small_scene: ServedScene) -> Iterator[Server]:
    context: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    authenticator = CurveAuthenticator(keys.allowed, context)
    authenticator.start()
    server = Server(
        [small_scene],
        bind="tcp://127.0.0.1:*",
        context=context,
        socket_options=server_socket_options(keys.server_secret),
    )
    server.start()
    yield server
    server.stop()
    authenticator.stop()
    context.destroy(linger=0)


# -- CurveZMQ ---------------------------------------------------------------------------------


def test_a_client_with_the_right_keys_is_answered(curve_server: Server, keys: Keys) -> None:
    options = client_socket_options(keys.server_public, keys.client_secret)
    with Client(curve_server.address, timeout=5.0, socket_options=options) as client:
        frame = client.query(0.5)
        assert (frame.scene, frame.step, frame.z.shape) == ("small", 50, (9,))
        assert client.ping() > 0


@pytest.mark.slow
@pytest.mark.parametrize("who", ["no keys", "unknown client key", "wrong server key"])
def test_a_client_without_the_right_keys_gets_nothing(
    curve_server: Server, keys: Keys, who: str
) -> None:
    options = {
        "no keys": None,
        "unknown client key": client_socket_options(keys.server_public, keys.stranger_secret),
        "wrong server key": client_socket_options(keys.impostor_public, keys.client_secret),
    }[who]
    timeout = 0.5
    with Client(curve_server.address, timeout=timeout, socket_options=options) as client:
        started = time.monotonic()
        with pytest.raises(Timeout):
            client.query(0.5)
        assert time.monotonic() - started < timeout + 1.0  # its timeout, not a hang
    # ...and the server still answers the right keys afterwards.
    good = client_socket_options(keys.server_public, keys.client_secret)
    with Client(curve_server.address, timeout=5.0, socket_options=good) as client:
        assert client.query(0.25).step == 25


def test_several_keyed_clients_at_once(curve_server: Server, keys: Keys) -> None:
    options = client_socket_options(keys.server_public, keys.client_secret)
    failures: list[str] = []

    def poll() -> None:
        with Client(curve_server.address, timeout=5.0, socket_options=options) as client:
            for k in range(100):
                step = client.query(k * 0.01).step
                if step != k:
                    failures.append(f"step {step} for {k}")

    threads = [threading.Thread(target=poll) for _ in range(3)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert not any(thread.is_alive() for thread in threads)
    assert failures == []


@pytest.mark.slow
def test_cli_serve_and_ping_with_curve_keys(keys: Keys) -> None:
    serve = subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", "rope", "--bind", "tcp://127.0.0.1:*",
         "--curve-secret", str(keys.server_secret), "--curve-clients", str(keys.allowed)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert serve.stdout is not None
        line = serve.stdout.readline()
        assert "listening on tcp://127.0.0.1:" in line and "CurveZMQ" in line, line
        address = line.split("listening on ", 1)[1].split()[0]
        keyed = ["--curve-server-key", str(keys.server_public), "--curve-secret"]
        ping = [*MEMBRANE, "ping", "--connect", address, "--timeout", "5"]
        good = subprocess.run([*ping, *keyed, str(keys.client_secret)], capture_output=True,
                              text=True, timeout=60)  # fmt: skip
        assert good.returncode == 0, good.stderr
        assert "pong from" in good.stdout
        query = [*MEMBRANE, "query", "--connect", address, "--t", "0.5", *keyed]
        answered = subprocess.run([*query, str(keys.client_secret)], capture_output=True,
                                  text=True, timeout=60)  # fmt: skip
        assert answered.returncode == 0 and "step 50" in answered.stdout, answered.stderr
        ping[-1] = "0.5"
        for extra in ([], [*keyed, str(keys.stranger_secret)]):
            refused = subprocess.run([*ping, *extra], capture_output=True, text=True, timeout=60)
            assert refused.returncode == 1
            assert "no reply" in refused.stderr
    finally:
        serve.terminate()
        serve.wait(10)
    assert serve.returncode == 0


@pytest.mark.slow
def test_daemon_with_curve_keys_and_a_scene_given_as_relative_paths(
    keys: Keys, tmp_path: Path
) -> None:
    """A daemon runs from /: relative key and scene paths must still mean what they meant."""
    work = tmp_path / "work"
    shutil.copytree(keys.allowed.parent, work)
    shutil.copy(REPO / "server/membrane_server/scenes/rope.toml", work / "my-rope.toml")
    with socket.socket() as probe:  # a free port; the daemon binds it a moment later
        probe.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    pidfile = tmp_path / "membrane.pid"
    started = subprocess.run(
        [*MEMBRANE, "serve", "--daemon", "--scene", "my-rope.toml", "--bind", address,
         "--pidfile", str(pidfile), "--logfile", str(tmp_path / "membrane.log"),
         "--curve-secret", "server/server.key_secret", "--curve-clients", "allowed"],
        capture_output=True, text=True, timeout=120, cwd=work,
    )  # fmt: skip
    assert started.returncode == 0, started.stderr
    pid = int(pidfile.read_text())
    try:
        options = client_socket_options(keys.server_public, keys.client_secret)
        with Client(address, timeout=5.0, socket_options=options) as client:
            frame = client.query(0.5)
            assert (frame.scene, frame.step) == ("my-rope", 50)
        with Client(address, timeout=0.5) as stranger, pytest.raises(Timeout):
            stranger.ping()
    finally:
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + 10
    while pidfile.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not pidfile.exists(), "the daemon did not stop on SIGTERM"


def test_key_files_that_cannot_be_used_are_named(keys: Keys, tmp_path: Path) -> None:
    with pytest.raises(CurveError, match=r"holds no secret key .*\.key_secret"):
        server_socket_options(keys.server_public)
    with pytest.raises(CurveError, match="holds no secret key"):
        client_socket_options(keys.server_public, keys.server_public)
    with pytest.raises(CurveError, match="no such key file"):
        server_socket_options(tmp_path / "missing.key_secret")
    garbage = tmp_path / "garbage.key_secret"
    garbage.write_bytes(b"\xff\x00 not a certificate")
    with pytest.raises(CurveError, match="not a ZeroMQ certificate"):
        client_socket_options(keys.server_public, garbage)


def test_client_key_folders_that_cannot_be_used_are_named(keys: Keys, tmp_path: Path) -> None:
    with pytest.raises(CurveError, match="no such directory"):
        CurveAuthenticator(tmp_path / "missing")
    with pytest.raises(CurveError, match="holds no client public key"):
        CurveAuthenticator(tmp_path)
    (tmp_path / "broken.key").write_text("public-key = nothing here\n")
    with pytest.raises(CurveError, match=r"broken\.key: not a ZeroMQ certificate"):
        CurveAuthenticator(tmp_path)
    assert CurveAuthenticator(keys.allowed).allowed == 1


@pytest.mark.slow
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["serve", "--curve-secret", "s.key_secret"], "--curve-secret and --curve-clients go"),
        (["serve", "--curve-secret", "/nowhere.key_secret", "--curve-clients", "/"],
         "/nowhere.key_secret: no such key file"),
        (["ping", "--curve-secret", "c.key_secret"], "--curve-server-key and --curve-secret go"),
        (["query", "--t", "0", "--curve-server-key", "/nowhere.key", "--curve-secret", "/x"],
         "/nowhere.key: no such key file"),
    ],
)  # fmt: skip
def test_cli_key_mistakes_are_one_line_and_exit_2(argv: list[str], message: str) -> None:
    result = subprocess.run([*MEMBRANE, *argv], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1, result.stderr
    assert message in result.stderr


# -- loopback by default ----------------------------------------------------------------------


def test_every_default_endpoint_is_loopback() -> None:
    parser = argparse.ArgumentParser()
    add_serve(parser.add_subparsers())
    serve_default = parser.parse_args(["serve"]).bind
    server_default = inspect.signature(Server).parameters["bind"].default
    for endpoint in (serve_default, server_default, DEFAULT_ADDRESS):
        assert endpoint.startswith("tcp://127.0.0.1:"), endpoint


@pytest.mark.parametrize(
    ("bind", "loopback"),
    [
        ("tcp://127.0.0.1:5555", True),
        ("tcp://localhost:*", True),
        ("tcp://[::1]:5555", True),
        ("ipc:///tmp/membrane.sock", True),
        ("tcp://0.0.0.0:5555", False),
        ("tcp://*:5555", False),
        ("tcp://192.168.1.20:5555", False),
        ("tcp://eth0:5555", False),
    ],
)
def test_binds_beyond_loopback_are_recognised(bind: str, loopback: bool) -> None:
    """`membrane serve` warns when such a bind has no CurveZMQ."""
    assert is_loopback_endpoint(bind) is loopback


# -- no pickle --------------------------------------------------------------------------------

# Deserialisers that can run code, and the calls that switch them on.
UNSAFE = re.compile(
    r"\bimport pickle\b|\bfrom pickle\b|\bcPickle\b|\bdill\b|\bjoblib\b|\bshelve\b|\bmarshal\b"
    r"|torch\.load|allow_pickle\s*=\s*True|yaml\.load\(|(?<![.\w])eval\(|(?<![.\w])exec\("
    r"|ext_hook|object_hook|object_pairs_hook"
)

# Everything the server process imports to serve any evaluator, in a fresh interpreter.
_LIST_SERVER_MODULES = textwrap.dedent(
    """
    import importlib, pkgutil, sys
    import membrane_client, membrane_server
    for package in (membrane_client, membrane_server):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            importlib.import_module(info.name)
    import membrane_models.exact  # what the exact evaluator loads on demand
    for name, module in sorted(sys.modules.items()):
        if name.split(".")[0] in ("membrane_client", "membrane_server", "membrane_models"):
            print(getattr(module, "__file__", None) or "")
    print("torch loaded:", "torch" in sys.modules)
    """
)


@pytest.mark.slow
def test_nothing_on_the_wire_or_served_uses_pickle() -> None:
    result = subprocess.run(
        [sys.executable, "-c", _LIST_SERVER_MODULES], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    *files, torch_line = result.stdout.splitlines()
    assert torch_line == "torch loaded: False"  # torch.load cannot even be reached
    sources = [Path(f) for f in files if f.endswith(".py")]
    assert any(p.name == "protocol.py" for p in sources) and len(sources) > 20
    offenders = [
        f"{path.relative_to(REPO)}:{number}: {line.strip()}"
        for path in sources
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if UNSAFE.search(line)
    ]
    assert offenders == []


def test_the_unsafe_pattern_catches_what_it_should() -> None:
    """Guards the guard: each of these lines must be flagged."""
    flagged = [
        "import pickle",
        "data = torch.load(path)",
        "np.load(file, allow_pickle=True)",
        "msgpack.unpackb(data, ext_hook=make_object)",
        "value = eval(text)",
    ]
    assert all(UNSAFE.search(line) for line in flagged)
    assert not UNSAFE.search("session.run(outputs)  # model.evaluate(...) is fine")


@pytest.mark.slow
def test_server_loads_only_onnx_json_and_toml(tmp_path: Path) -> None:
    """The files a server opens to load a scene and its model, recorded by an audit hook in a
    fresh interpreter: ONNX graphs (protobuf), JSON manifests, TOML scenes, nothing else of
    ours (no pickle, no npz, no checkpoint)."""
    scene = tmp_path / "skin.toml"
    scene.write_text(
        'model = "membrane-forced"\nevaluator = "separable"\ndt = 0.01\nduration = 1.0\n'
        "[lattice]\nnx = 4\nny = 4\n"
    )
    script = textwrap.dedent(
        f"""
        import sys
        from membrane_server.served import ServedScene
        from membrane_server.scene import load_scene
        opened = []
        sys.addaudithook(lambda event, args: opened.append(str(args[0]))
                         if event == "open" and isinstance(args[0], str) else None)
        ServedScene.load(load_scene({str(scene)!r}))
        print("\\n".join(opened))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    ours = (str(REPO), str(tmp_path))
    opened = {Path(line) for line in result.stdout.splitlines() if line.startswith(ours)}
    code = {".py", ".pyc", ".so"}  # lazily imported modules of ours, not data
    data = {path for path in opened if path.suffix not in code}
    assert {path.suffix for path in data} == {".onnx", ".json", ".toml"}, sorted(data)
    assert scene in data


# -- limits -----------------------------------------------------------------------------------


def _scene(**fields: object) -> dict[str, object]:
    data: dict[str, object] = {
        "name": "limits", "model": "membrane-forced", "evaluator": "exact",
        "lattice": {"nx": 20, "ny": 20}, "dt": 0.01, "duration": 1.0,
    }  # fmt: skip
    data.update(fields)
    return data


@pytest.mark.parametrize(
    "lattice",
    [{"nx": 257, "ny": 256}, {"nx": MAX_LATTICE_POINTS + 1}, {"nx": 1, "ny": 10**9}],
)
def test_a_lattice_over_the_limit_is_refused_naming_it(lattice: dict[str, int]) -> None:
    limit = rf"lattice.*(more than the limit|less than or equal to) {MAX_LATTICE_POINTS}"
    with pytest.raises(SceneError, match=limit):
        scene_from_dict(_scene(lattice=lattice))


def test_a_point_list_over_the_limit_is_refused() -> None:
    points = [[0.5, 0.5]] * (MAX_LATTICE_POINTS + 1)
    with pytest.raises(SceneError, match=f"more than the limit {MAX_LATTICE_POINTS}"):
        scene_from_dict(_scene(lattice={"points": points}))


def test_the_largest_lattice_is_accepted() -> None:
    assert scene_from_dict(_scene(lattice={"nx": 256, "ny": 256})).lattice.shape == (256, 256)


def test_a_table_over_its_memory_limit_is_refused_at_load(
    test_models: dict[str, TestModel],
) -> None:
    model = test_models["membrane"].manifest_path
    scene = scene_from_dict(_scene(model=str(model), evaluator="table", table_max_bytes=100_000))
    with pytest.raises(SceneError, match=r"table_max_bytes: .* 161600 bytes, more than .* 100000"):
        ServedScene.load(scene)
    # The default budget is bounded too: a 1 us step over 1 s does not fit.
    fine = scene_from_dict(_scene(model=str(model), evaluator="table", dt=1e-6))
    assert fine.table_max_bytes == DEFAULT_TABLE_MAX_BYTES
    with pytest.raises(SceneError, match="table_max_bytes"):
        ServedScene.load(fine)


@pytest.mark.slow
def test_serve_refuses_an_oversized_table_in_one_line(tmp_path: Path) -> None:
    scene = tmp_path / "big.toml"
    scene.write_text(
        'model = "membrane-forced"\nevaluator = "exact"\ndt = 0.01\nduration = 1.0\n'
        "[lattice]\nnx = 300\nny = 300\n"
    )
    result = subprocess.run(
        [*MEMBRANE, "serve", "--scene", str(scene), "--bind", "tcp://127.0.0.1:*"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1, result.stderr
    assert "more than the limit 65536" in result.stderr


@pytest.mark.slow
def test_an_oversized_reply_times_the_client_out_instead_of_filling_its_memory() -> None:
    """A rogue server sending more than MAX_REPLY_BYTES: the client drops it and times out."""
    rogue: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.ROUTER)
    rogue.setsockopt(zmq.LINGER, 0)
    port = rogue.bind_to_random_port("tcp://127.0.0.1")
    sent: list[int] = []

    def answer_hugely() -> None:
        if rogue.poll(5000):
            envelope = rogue.recv_multipart()[:-1]
            reply = encode(ok_reply(1, junk=b"\x00" * (MAX_REPLY_BYTES + 1)))
            rogue.send_multipart([*envelope, reply])
            sent.append(len(reply))

    thread = threading.Thread(target=answer_hugely)
    thread.start()
    try:
        with Client(f"tcp://127.0.0.1:{port}", timeout=1.0) as client, pytest.raises(Timeout):
            client.ping()
    finally:
        thread.join(10)
        rogue.close(linger=0)
    assert sent and sent[0] > MAX_REPLY_BYTES
