"""Fault injection with real processes: a server killed and restarted under a polling client,
SIGTERM in the middle of a reply, and model files altered on disk.

Servers run as `membrane serve` subprocesses on 127.0.0.1; clients run in subprocesses too, so
that "never hangs at exit" is an observed process exit, not an assumption.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
import zmq
from serve_process import MEMBRANE, LineReader, ServeProcess

from membrane_client import Client
from membrane_client.protocol import Request, decode, unpack_array
from membrane_models.artifacts.manifest import ManifestError
from membrane_server.scene import load_scene, scene_from_dict
from membrane_server.served import ServedScene

if TYPE_CHECKING:
    from onnx_graphs import TestModel


# A simulator-like loop: query every step, report each change of state on one stdout line, exit
# (without closing the client: the interpreter's exit must not hang on it) when told to.
CLIENT_LOOP = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from membrane_client import Client, Timeout

    address, timeout, stop_file = sys.argv[1], float(sys.argv[2]), Path(sys.argv[3])
    client = Client(address, timeout=timeout)
    state, k = None, 0
    deadline = time.monotonic() + 120
    while not stop_file.exists() and time.monotonic() < deadline:
        started = time.monotonic()
        try:
            frame = client.query((k % 101) * 0.01)
            event = "ok" if frame.step == k % 101 else f"wrong step {frame.step} for {k % 101}"
        except Timeout:
            event = f"timeout {time.monotonic() - started:.3f}"
        if event.split()[0] != state:
            print(event, flush=True)
            state = event.split()[0]
        k += 1
        time.sleep(0.002)
    print("exiting", flush=True)
    """
)


@pytest.fixture
def servers() -> Iterator[list[ServeProcess]]:
    """Server subprocesses started by a test; killed at teardown if still running."""
    started: list[ServeProcess] = []
    yield started
    for server in started:
        server.close()


def _port(address: str) -> str:
    return address.rsplit(":", 1)[1]


# -- kill and restart -------------------------------------------------------------------------


@pytest.mark.slow
def test_killed_server_times_out_the_client_which_recovers_and_exits_promptly(
    servers: list[ServeProcess], tmp_path: Path
) -> None:
    timeout = 0.5
    servers.append(ServeProcess("rope"))
    address = servers[0].address
    stop_file = tmp_path / "stop"
    client = subprocess.Popen(
        [sys.executable, "-c", CLIENT_LOOP, address, str(timeout), str(stop_file)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert client.stdout is not None
        events = LineReader(client.stdout)
        events.wait_for("ok")

        servers[0].process.send_signal(signal.SIGKILL)  # no goodbye: the reply never comes
        servers[0].process.wait(10)
        waited = float(events.wait_for("timeout", timeout=10).split()[1])
        assert timeout <= waited <= timeout + 0.5  # Timeout within the client's timeout

        servers.append(ServeProcess("rope", bind=f"tcp://127.0.0.1:{_port(address)}"))
        events.wait_for("ok", timeout=30)  # the same client object recovers by itself

        stop_file.touch()
        started = time.monotonic()
        assert client.wait(timeout=10) == 0
        exit_seconds = time.monotonic() - started
        lines = events.rest()
    finally:
        if client.poll() is None:
            client.kill()
            client.wait()
    assert lines[-1] == "exiting"
    assert not [line for line in lines if line.startswith("wrong")]
    assert exit_seconds < 5.0, f"the client took {exit_seconds:.1f} s to exit"


@pytest.mark.slow
def test_a_client_exits_at_once_after_a_timeout_with_a_request_still_queued() -> None:
    """Nobody listens: the request waits in the socket's queue; exit must still be immediate."""
    script = textwrap.dedent(
        """
        import sys, zmq
        from membrane_client import Client, Timeout
        silent = zmq.Context.instance().socket(zmq.ROUTER)  # accepts, never answers
        port = silent.bind_to_random_port("tcp://127.0.0.1")
        client = Client(f"tcp://127.0.0.1:{port}", timeout=0.2, retries=1)
        try:
            client.ping()
        except Timeout as exc:
            print("timeout:", exc, flush=True)
        lost = Client("tcp://127.0.0.1:1", timeout=0.2)  # nothing there: never connects
        try:
            lost.ping()
        except Timeout:
            print("timeout 2", flush=True)
        silent.close(linger=0)
        zmq.Context.instance().term()  # blocks forever if any socket kept a message pending
        print("terminated", flush=True)
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 0, result.stderr
    assert "after 2 attempts" in result.stdout
    assert result.stdout.splitlines()[-2:] == ["timeout 2", "terminated"]


# -- SIGTERM: finish the reply in flight --------------------------------------------------------


@pytest.mark.slow
def test_sigterm_delivers_every_reply_it_answered_then_exits(
    servers: list[ServeProcess], tmp_path: Path
) -> None:
    """SIGTERM while big (512 KB) replies wait in the server's queue for a client that has not
    read them yet: the server stops after the request in flight, and every request it says it
    answered reaches the client whole once the client reads."""
    scene = tmp_path / "long-rope.toml"
    scene.write_text(
        textwrap.dedent(
            """
            model = "string-forced"
            evaluator = "exact"
            dt = 0.01
            duration = 1.0
            snapping = "linear"
            table_max_bytes = 1  # frames computed per query: each takes a few ms
            [lattice]
            nx = 65536
            """
        )
    )
    servers.append(ServeProcess(str(scene)))
    server = servers[0]
    sent = 200  # more than it can answer before the signal
    socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.DEALER)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, 3_000)
    # Hold the replies back: a one-message receive queue and a small TCP window, so that the
    # server's own queue still holds answered replies when the signal comes.
    socket.setsockopt(zmq.RCVHWM, 1)
    socket.setsockopt(zmq.RCVBUF, 4096)
    socket.connect(server.address)
    replies = []
    try:
        for k in range(sent):  # pipelined: the server works through them one by one
            query = Request("query", k, t=0.005 + 0.01 * k, dtype="<f8")
            socket.send_multipart([b"", query.to_wire()])
        # 2.5 ms (quiet machine) to 20 ms (loaded) per request: 7 to 60 answered, unread,
        # a backlog (<= 30 MB) that drains well within the server's shutdown linger.
        time.sleep(0.15)
        server.process.send_signal(signal.SIGTERM)
        while True:
            try:
                replies.append(decode(socket.recv_multipart()[-1]))
            except zmq.Again:
                break
    finally:
        socket.close(linger=0)
    assert server.process.wait(timeout=20) == 0
    log = server.stderr.rest()
    stopped = [line for line in log if "stopped after" in line]
    assert stopped, log
    counts = stopped[-1].split("stopped after ")[1].split()
    answered, dropped = int(counts[0]), int(counts[2].lstrip("("))
    assert "membrane serve: stopped" in log
    assert 1 <= len(replies) < sent  # it stopped early...
    # ...and nothing it answered was lost, but for the replies past this peer's memory budget,
    # which the server dropped (and counted) rather than queue without bound.
    assert len(replies) == answered - dropped
    ids = [reply["id"] for reply in replies]
    assert ids == sorted(ids)
    for reply in replies:
        assert reply["ok"] is True
        assert unpack_array(reply["z"]).shape == (65536,)
    # Its socket is closed: the port can be bound again at once.
    again = ServeProcess("rope", bind=f"tcp://127.0.0.1:{_port(server.address)}")
    servers.append(again)
    with Client(again.address, timeout=5.0) as client:
        assert client.query(0.5).step == 50


# -- altered model files ----------------------------------------------------------------------


def _copy_model(model: TestModel, directory: Path) -> Path:
    """Copy a test model's manifest and graphs; returns the copied manifest."""
    manifest = json.loads(model.manifest_path.read_text())
    for graph in manifest["graphs"].values():
        shutil.copy(model.manifest_path.parent / graph["file"], directory / graph["file"])
    target = directory / model.manifest_path.name
    shutil.copy(model.manifest_path, target)
    return target


def _scene_on(manifest: Path, evaluator: str) -> Any:
    return scene_from_dict(
        {"name": "altered", "model": str(manifest), "evaluator": evaluator,
         "lattice": {"nx": 4, "ny": 4}, "dt": 0.1, "duration": 1.0}
    )  # fmt: skip


@pytest.mark.parametrize(
    ("role", "evaluator"), [("full", "network"), ("space", "separable"), ("time", "separable")]
)
def test_a_flipped_byte_in_a_graph_is_refused_at_load(
    test_models: dict[str, TestModel], tmp_path: Path, role: str, evaluator: str
) -> None:
    manifest = _copy_model(test_models["membrane"], tmp_path)
    graph = tmp_path / json.loads(manifest.read_text())["graphs"][role]["file"]
    data = bytearray(graph.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit: still a loadable ONNX file, perhaps
    graph.write_bytes(bytes(data))
    with pytest.raises(ManifestError, match=rf"{graph.name} sha256 .* does not match"):
        ServedScene.load(_scene_on(manifest, evaluator))


def test_a_truncated_graph_is_refused_at_load(
    test_models: dict[str, TestModel], tmp_path: Path
) -> None:
    manifest = _copy_model(test_models["membrane"], tmp_path)
    graph = tmp_path / json.loads(manifest.read_text())["graphs"]["full"]["file"]
    graph.write_bytes(graph.read_bytes()[:100])
    with pytest.raises(ManifestError, match="file altered or corrupted"):
        ServedScene.load(_scene_on(manifest, "network"))


def test_a_graph_swapped_for_another_model_is_refused(
    test_models: dict[str, TestModel], tmp_path: Path
) -> None:
    """A valid ONNX file of the right shape, but not the one the manifest lists."""
    manifest = _copy_model(test_models["membrane"], tmp_path)
    listed = json.loads(manifest.read_text())["graphs"]["full"]["file"]
    other = test_models["membrane_full_only"].full_path
    shutil.copy(other, tmp_path / listed)
    with pytest.raises(ManifestError, match="does not match the manifest"):
        ServedScene.load(_scene_on(manifest, "network"))


def test_a_missing_graph_is_named(test_models: dict[str, TestModel], tmp_path: Path) -> None:
    manifest = _copy_model(test_models["membrane"], tmp_path)
    listed = json.loads(manifest.read_text())["graphs"]["time"]["file"]
    (tmp_path / listed).unlink()
    with pytest.raises(ManifestError, match=f"graph file .*{listed} is missing"):
        ServedScene.load(_scene_on(manifest, "separable"))


@pytest.mark.slow
def test_serve_refuses_an_altered_model_in_one_line(
    test_models: dict[str, TestModel], tmp_path: Path
) -> None:
    manifest = _copy_model(test_models["membrane"], tmp_path)
    graph = tmp_path / json.loads(manifest.read_text())["graphs"]["full"]["file"]
    graph.write_bytes(graph.read_bytes() + b"\x00")  # appended junk
    scene = tmp_path / "altered.toml"
    scene.write_text(
        f'model = "{manifest.name}"\nevaluator = "network"\ndt = 0.1\nduration = 1.0\n'
        "[lattice]\nnx = 4\nny = 4\n"
    )
    load_scene(scene)  # the scene file itself is fine
    result = subprocess.run(
        [*MEMBRANE, "serve", "--scene", str(scene), "--bind", "tcp://127.0.0.1:*"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1, result.stderr
    assert "does not match the manifest" in result.stderr
    assert "Traceback" not in result.stderr


def test_an_altered_manifest_is_refused(test_models: dict[str, TestModel], tmp_path: Path) -> None:
    """Editing the hash in the manifest to someone else's graph is a mismatch too."""
    manifest = _copy_model(test_models["membrane"], tmp_path)
    data = json.loads(manifest.read_text())
    data["graphs"]["full"]["sha256"] = "0" * 64
    manifest.write_text(json.dumps(data))
    with pytest.raises(ManifestError, match="does not match"):
        ServedScene.load(_scene_on(manifest, "network"))
    manifest.write_text(json.dumps(data)[:-20])  # cut short: not JSON any more
    with pytest.raises(ValueError, match="cannot read manifest"):
        ServedScene.load(_scene_on(manifest, "network"))
