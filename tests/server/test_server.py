"""The server on real ZeroMQ sockets (127.0.0.1, random ports): answers, errors, policies, stats."""

from __future__ import annotations

import json
import math
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import msgpack
import numpy as np
import pytest
import zmq

from membrane_cli.dispatcher import main as membrane_main
from membrane_client import Client, ServerError, Timeout
from membrane_client.protocol import MAX_REQUEST_BYTES, Request, decode, encode, unpack_array
from membrane_models.exact import exact_solution
from membrane_models.problems import make_problem
from membrane_server.server import BindError, Server

EVALUATOR_KINDS = ["network", "separable", "table", "exact"]


@contextmanager
def raw_socket(
    address: str, kind: int = zmq.REQ, timeout_s: float = 5.0
) -> Iterator[zmq.Socket[bytes]]:
    socket: zmq.Socket[bytes] = zmq.Context.instance().socket(kind)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, int(timeout_s * 1000))
    socket.connect(address)
    try:
        yield socket
    finally:
        socket.close(linger=0)


def exchange(address: str, payload: bytes) -> dict[str, Any]:
    with raw_socket(address) as socket:
        socket.send(payload)
        return decode(socket.recv())


def good_query(address: str, scene: str, t: float, request_id: int = 99) -> dict[str, Any]:
    return exchange(address, Request("query", request_id, scene=scene, t=t).to_wire())


# -- serving frames -------------------------------------------------------------------------


@pytest.mark.parametrize("kind", EVALUATOR_KINDS)
def test_thousand_queries_serve_their_step_times(evaluator_server: Server, kind: str) -> None:
    served = evaluator_server.dispatcher.scenes[kind]
    with Client(evaluator_server.address, timeout=5.0, scene=kind) as client:
        for k in range(1000):
            t = (k % 101) * 0.01
            frame = client.query(t)
            assert frame.t == t
            assert frame.step == k % 101
            assert frame.domain == "inside"
            if k % 101 in (0, 50, 100) and k < 101:
                expected = served.evaluator.frame(t)
                np.testing.assert_array_equal(frame.z.reshape(-1), np.float32(expected))


@pytest.mark.parametrize("kind", EVALUATOR_KINDS)
def test_past_the_duration_holds_the_last_frame(evaluator_server: Server, kind: str) -> None:
    with Client(evaluator_server.address, timeout=5.0, scene=kind) as client:
        last = client.query(1.0)
        for t in (1.2, 10.0, 1e9):
            held = client.query(t)
            assert (held.step, held.t, held.domain, held.requested_t) == (100, 1.0, "held", t)
            np.testing.assert_array_equal(held.z, last.z)


@pytest.mark.parametrize(
    ("policy", "domain"), [("clamp", "clamped"), ("hold", "held"), ("error", None)]
)
def test_policies_on_a_live_server(
    start_server: Any, make_scene: Any, policy: str, domain: str | None
) -> None:
    lattice = {"nx": 4, "ny": 4}
    scene = make_scene("membrane-forced", "exact", name="s", policy=policy, lattice=lattice)
    server = start_server([scene])
    with Client(server.address, timeout=5.0) as client:
        assert client.query(1.0).domain == "inside"
        if domain is None:
            with pytest.raises(ServerError) as caught:
                client.query(1.5)
            assert caught.value.code == "out_of_domain"
            assert client.query(0.5).step == 50  # and the next good query is answered
        else:
            for t, step in ((1.5, 100), (-0.5, 0)):
                frame = client.query(t)
                assert (frame.step, frame.domain) == (step, domain)


def test_extreme_times(evaluator_server: Server) -> None:
    with Client(evaluator_server.address, timeout=5.0, scene="exact") as client:
        tiny = client.query(-1e-12)
        assert (tiny.step, tiny.t, tiny.domain) == (0, 0.0, "inside")
        huge = client.query(1e9)
        assert (huge.step, huge.domain) == (100, "held")


def test_linear_snapping_interpolates(start_server: Any, make_scene: Any) -> None:
    scene = make_scene("membrane-forced", "exact", name="s", snapping="linear")
    server = start_server([scene])
    with Client(server.address, timeout=5.0) as client:
        a, b = client.query(0.25), client.query(0.26)
        mid = client.query(0.2575)
        assert (mid.step, mid.t) == (25, 0.2575)
        expected = 0.25 * a.z.astype(np.float64) + 0.75 * b.z
        np.testing.assert_allclose(mid.z, expected, rtol=1e-5, atol=1e-12)


def test_exact_scene_matches_the_exact_solution(evaluator_server: Server) -> None:
    with Client(evaluator_server.address, timeout=5.0, scene="exact") as client:
        info = client.describe()
        frame = client.query(0.5)
    solution = exact_solution(make_problem("membrane-forced"))
    reference = solution.at_points(info.points, np.array([0.5]))[:, 0]
    # The wire carries float32: the served values are the exact ones rounded to float32.
    np.testing.assert_array_equal(frame.z.reshape(-1), reference.astype(np.float32))
    assert np.abs(reference).max() == pytest.approx(4.8e-4, rel=0.1)


# -- malformed input --------------------------------------------------------------------------


BAD_REQUESTS: list[tuple[bytes, str, int | None]] = [
    (b"\x93\x01\x02", "bad_message", None),  # a msgpack list
    # random bytes (seeded: the same in every collecting process), never valid msgpack
    (random.Random(7).randbytes(64) + b"\xc1", "bad_message", None),
    (b"", "bad_message", None),
    (encode({"v": 2, "id": 5, "op": "query", "t": 0.5}), "bad_version", 5),
    (encode({"id": 6, "op": "ping"}), "bad_version", 6),
    (encode({"v": 1, "id": 7, "op": "teleport"}), "unknown_op", 7),
    (encode({"v": 1, "id": 8, "op": "query", "scene": "exact", "t": math.nan}), "invalid_time", 8),
    (encode({"v": 1, "id": 9, "op": "query", "scene": "exact", "t": math.inf}), "invalid_time", 9),
    (encode({"v": 1, "id": 10, "op": "query", "scene": "exact"}), "bad_request", 10),
    (encode({"v": 1, "id": 11, "op": "query", "scene": "exact", "t": "0.5"}), "bad_request", 11),
    (encode({"v": 1, "id": 12, "op": "query", "scene": "exact", "t": True}), "bad_request", 12),
    (encode({"v": 1, "id": 13, "op": "query", "t": 0.5}), "unknown_scene", 13),
    (encode({"v": 1, "id": 14, "op": "query", "scene": "skin", "t": 0.5}), "unknown_scene", 14),
    (encode({"v": 1, "id": 15, "op": "query", "scene": 3, "t": 0.5}), "bad_request", 15),
    (encode({"v": 1, "id": "x", "op": "ping"}), "bad_request", None),
    (encode({"v": 1, "id": -1, "op": "ping"}), "bad_request", None),
    (encode({"v": 1, "op": "ping"}), "bad_request", None),
    (encode({"v": 1, "id": 16, "op": 4}), "bad_request", 16),
    (encode({"v": 1, "id": 17, "op": "ping", "session": "s" * 65}), "bad_request", 17),
    (encode({"v": 1, "id": 18, "op": "ping", "session": 12}), "bad_request", 18),
    (
        encode({"v": 1, "id": 19, "op": "query", "scene": "exact", "t": 0, "dtype": "<i4"}),
        "bad_request",
        19,
    ),
]


@pytest.mark.parametrize(("payload", "code", "request_id"), BAD_REQUESTS)
def test_bad_input_gets_an_error_reply_and_the_next_query_is_answered(
    evaluator_server: Server, payload: bytes, code: str, request_id: int | None
) -> None:
    address = evaluator_server.address
    reply = exchange(address, payload)
    assert reply["v"] == 1
    assert reply["ok"] is False
    assert reply["id"] == request_id
    assert reply["error"]["code"] == code
    assert isinstance(reply["error"]["message"], str) and reply["error"]["message"]
    good = good_query(address, "exact", 0.3)
    assert (good["ok"], good["step"], good["t"]) == (True, 30, 0.3)


def test_several_payload_frames_are_a_bad_message(evaluator_server: Server) -> None:
    with raw_socket(evaluator_server.address) as socket:
        socket.send_multipart([Request("ping", 1).to_wire(), b"extra"])
        reply = decode(socket.recv())
    assert reply["error"]["code"] == "bad_message"


def test_dealer_without_delimiter_is_answered(evaluator_server: Server) -> None:
    with raw_socket(evaluator_server.address, zmq.DEALER) as socket:
        socket.send(Request("ping", 3).to_wire())
        reply = decode(socket.recv())
    assert (reply["ok"], reply["id"], reply["pong"]) == (True, 3, True)


def test_oversized_request_is_dropped_and_others_are_served(evaluator_server: Server) -> None:
    address = evaluator_server.address
    with Client(address, timeout=0.5) as big:
        with pytest.raises(Timeout):
            big.request("describe", scene="x" * (MAX_REQUEST_BYTES + 1024))
        assert big.ping() > 0  # a fresh socket (Lazy Pirate) is a fresh connection
    assert good_query(address, "exact", 0.1)["step"] == 10


def test_a_client_that_never_reads_stalls_nobody(evaluator_server: Server) -> None:
    address = evaluator_server.address
    with raw_socket(address, zmq.DEALER) as greedy:
        for k in range(200):  # requests whose replies nobody reads
            greedy.send_multipart([b"", Request("query", k, scene="table", t=0.5).to_wire()])
        with Client(address, timeout=2.0, scene="table") as client:
            for k in range(20):
                assert client.query(k * 0.01).step == k


def test_several_clients_at_once(evaluator_server: Server) -> None:
    failures: list[str] = []

    def run(scene: str) -> None:
        with Client(evaluator_server.address, timeout=5.0, scene=scene) as client:
            for k in range(300):
                frame = client.query((k % 101) * 0.01)
                if frame.step != k % 101 or frame.scene != scene:
                    failures.append(f"{scene}: step {frame.step} for k = {k}")

    threads = [threading.Thread(target=run, args=(kind,)) for kind in EVALUATOR_KINDS]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60.0)
    assert not any(thread.is_alive() for thread in threads)
    assert failures == []


# -- several scenes, describe, stats ----------------------------------------------------------


def test_describe_fields(evaluator_server: Server) -> None:
    with Client(evaluator_server.address, timeout=5.0, scene="separable") as client:
        info = client.describe()
    assert (info.name, info.shape, info.steps, info.dt, info.duration) == (
        "separable", (20, 20), 101, 0.01, 1.0,
    )  # fmt: skip
    assert info.points.shape == (400, 2)
    assert info.points.dtype == np.float64
    np.testing.assert_array_equal(info.points[22], [1 / 19, 2 / 19])  # x-major grid, float64
    assert (info.policy, info.snapping, info.evaluator, info.axis) == (
        "hold", "nearest", "separable", "z",
    )  # fmt: skip
    assert info.evaluator_info["rank"] == 8
    assert info.model["name"] == "membrane-test"
    assert info.model["problem"] == "membrane-forced"
    assert set(info.model["sha256"]) == {"full", "space", "time"}
    assert "error" in info.model
    assert set(info.units) == {"time", "lattice", "displacement", "world"}


def test_describe_exact_scene_reports_modes(evaluator_server: Server) -> None:
    with Client(evaluator_server.address, timeout=5.0, scene="exact") as client:
        info = client.describe()
    assert info.evaluator == "exact"
    assert info.evaluator_info["modes"] > 0
    assert info.evaluator_info["truncation_error"] < 1e-8


def test_hello_lists_scenes_and_limits(evaluator_server: Server) -> None:
    with Client(evaluator_server.address, timeout=5.0, session="me") as client:
        hello = client.hello()
    assert hello.protocol == 1
    assert hello.server.startswith("membrane ")
    assert set(hello.scenes) == set(EVALUATOR_KINDS)
    assert hello.default_scene is None
    assert hello.session == "me"
    film = {"hello", "describe", "query", "stats", "ping"}
    live = {"open", "step", "read", "reset", "close", "steps", "step_columns"}
    assert set(hello.ops) == film | live
    assert hello.limits is not None and hello.limits.max_request_bytes == MAX_REQUEST_BYTES


def test_stats_count_requests_errors_and_latency(start_server: Any, make_scene: Any) -> None:
    server = start_server([make_scene("membrane-forced", "exact", name="s", policy="error")])
    with Client(server.address, timeout=5.0) as client:
        for k in range(10):
            client.query(k * 0.1)
        with pytest.raises(ServerError):
            client.query(2.0)
        client.ping()
        stats = client.stats()
    assert stats.requests == 13  # describe + 10 queries + 1 refused + ping
    assert stats.ops == {"describe": 1, "query": 11, "ping": 1}
    assert stats.errors == {"out_of_domain": 1}
    assert stats.scenes == {"s": 10}
    assert stats.sessions == 1
    latency = stats.latency_us
    assert latency is not None and latency["count"] == 13
    assert 0 < latency["p50"] <= latency["p90"] <= latency["p99"] <= latency["max"]
    assert stats.uptime_s is not None and stats.uptime_s > 0


def test_single_scene_server_needs_no_scene_name(membrane_server: Server) -> None:
    with Client(membrane_server.address, timeout=5.0) as client:
        frame = client.query(0.5)
        assert (frame.scene, frame.step, frame.z.shape) == ("membrane", 50, (20, 20))


def test_duplicate_scene_names_are_refused(make_scene: Any) -> None:
    scene = make_scene("membrane-forced", "exact", name="twin", lattice={"nx": 2, "ny": 2})
    with pytest.raises(ValueError, match="distinct"):
        Server([scene, scene], bind="tcp://127.0.0.1:*")


def test_bind_failure_is_a_bind_error(membrane_server: Server, make_scene: Any) -> None:
    scene = make_scene("membrane-forced", "exact", name="s", lattice={"nx": 2, "ny": 2})
    with pytest.raises(BindError, match="cannot bind"):  # a UserError: one line at the CLI
        Server([scene], bind=membrane_server.address).start()


# -- shutdown ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_stop_finishes_and_closes(make_scene: Any) -> None:
    scene = make_scene("membrane-forced", "exact", name="s", lattice={"nx": 3, "ny": 3})
    server = Server([scene], bind="tcp://127.0.0.1:*")
    address = server.start()
    errors: list[BaseException] = []

    def poll() -> None:
        try:
            with Client(address, timeout=1.0) as client:
                for k in range(100_000):
                    client.query((k % 101) * 0.01)
        except Timeout:
            return  # the server went away: expected
        except BaseException as exc:
            errors.append(exc)

    poller = threading.Thread(target=poll)
    poller.start()
    time.sleep(0.3)
    started = time.monotonic()
    server.stop()
    assert time.monotonic() - started < 2.0
    poller.join(5.0)
    assert not poller.is_alive()
    assert errors == []
    assert server.stats.requests > 10
    with Client(address, timeout=0.3) as client, pytest.raises(Timeout):
        client.ping()


# -- the command line -------------------------------------------------------------------------


def test_cli_query_json_matches_the_evaluator(
    evaluator_server: Server, capsys: pytest.CaptureFixture[str]
) -> None:
    connect = ["--connect", evaluator_server.address]
    for kind in ("network", "separable", "table"):
        assert membrane_main(["query", *connect, "--scene", kind, "--t", "0.5", "--json"]) == 0
        data = json.loads(capsys.readouterr().out)
        assert (data["t"], data["step"], data["shape"]) == (0.5, 50, [20, 20])
        z = np.asarray(data["z"]).reshape(-1)
        reference = evaluator_server.dispatcher.scenes["network"].evaluator.frame(0.5)
        assert np.linalg.norm(z - reference) / np.linalg.norm(reference) <= 1e-6


def test_cli_query_float64_matches_the_exact_solution(
    evaluator_server: Server, capsys: pytest.CaptureFixture[str]
) -> None:
    connect = ["--connect", evaluator_server.address, "--scene", "exact"]
    assert membrane_main(["query", *connect, "--t", "0.5", "--json", "--float64"]) == 0
    z = np.asarray(json.loads(capsys.readouterr().out)["z"]).reshape(-1)
    points = evaluator_server.dispatcher.scenes["exact"].evaluator.points
    reference = exact_solution(make_problem("membrane-forced")).at_points(points, np.array([0.5]))
    assert np.linalg.norm(z - reference[:, 0]) / np.linalg.norm(reference) <= 1e-8


def test_cli_query_summary(membrane_server: Server, capsys: pytest.CaptureFixture[str]) -> None:
    assert membrane_main(["query", "--connect", membrane_server.address, "--t", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "scene membrane: step 50, t = 0.5 s" in out
    assert "lattice 20 x 20: max |z| =" in out


@pytest.mark.parametrize(("t", "code"), [("nan", 2), ("inf", 2)])
def test_cli_query_bad_time_exits_2(
    membrane_server: Server, capsys: pytest.CaptureFixture[str], t: str, code: int
) -> None:
    assert membrane_main(["query", "--connect", membrane_server.address, "--t", t]) == code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "invalid_time" in err


def test_cli_ping(membrane_server: Server, capsys: pytest.CaptureFixture[str]) -> None:
    assert membrane_main(["ping", "--connect", membrane_server.address]) == 0
    assert "pong from" in capsys.readouterr().out


@pytest.mark.slow
def test_serve_subprocess_answers_and_stops_on_sigterm() -> None:
    command = [sys.executable, "-m", "membrane_cli", "serve", "--scene", "rope"]
    process = subprocess.Popen(
        [*command, "--bind", "tcp://127.0.0.1:*"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert "listening on tcp://127.0.0.1:" in line, line
        address = line.split("listening on ", 1)[1].split()[0]
        with Client(address, timeout=5.0) as client:
            frame = client.query(0.5)
            assert (frame.scene, frame.z.shape, frame.step) == ("rope", (100,), 50)
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=10) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


@pytest.mark.slow
def test_serve_with_a_bad_scene_exits_2() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "membrane_cli", "serve", "--scene", "nowhere"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1
    assert "unknown scene 'nowhere'" in result.stderr


@pytest.mark.slow
def test_serve_on_a_busy_port_exits_2(membrane_server: Server) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "membrane_cli", "serve", "--scene", "rope",
         "--bind", membrane_server.address],
        capture_output=True,
        text=True,
        timeout=60,
    )  # fmt: skip
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1
    assert "cannot bind" in result.stderr


def test_reply_arrays_are_little_endian_float32(evaluator_server: Server) -> None:
    reply = msgpack.unpackb(
        _raw_bytes(evaluator_server.address, Request("query", 1, scene="table", t=0.5).to_wire())
    )
    assert reply["z"]["dtype"] == "<f4"
    assert unpack_array(reply["z"]).shape == (20, 20)


def _raw_bytes(address: str, payload: bytes) -> bytes:
    with raw_socket(address) as socket:
        socket.send(payload)
        data: bytes = socket.recv()
        return data


def test_a_spinning_server_answers_like_a_sleeping_one() -> None:
    """``spin`` changes how the loop waits, never what it answers."""
    with (
        Server(["rope"], bind="tcp://127.0.0.1:*", spin=0.002) as spinning,
        Server(["rope"], bind="tcp://127.0.0.1:*") as sleeping,
        Client(spinning.address, timeout=5.0) as a,
        Client(sleeping.address, timeout=5.0) as b,
    ):
        for k in range(0, 101, 7):
            assert a.query(k * 0.01).z.tobytes() == b.query(k * 0.01).z.tobytes()
            time.sleep(0.003)  # past the spin: the loop blocks, then wakes for the next


@pytest.mark.parametrize("spin", [-1e-6, 0.2, math.nan])
def test_spin_out_of_range_is_refused(spin: float) -> None:
    with pytest.raises(ValueError, match=r"spin must be between 0 and 0\.1 s"):
        Server(["rope"], bind="tcp://127.0.0.1:*", spin=spin)


@pytest.mark.parametrize("value", ["-1", "200000", "nan"])
def test_cli_spin_out_of_range_exits_2(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert membrane_main(["serve", "--scene", "rope", f"--spin-us={value}"]) == 2
    assert "--spin-us must be between 0 and 100000" in capsys.readouterr().err
