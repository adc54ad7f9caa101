"""The load tester: real ZeroMQ sockets, real client processes, the echo server and a live server.

Timing figures are never asserted as performance: only what the accounting must show (a stall
200 ms long shows as latencies near 200 ms in the corrected percentiles and not in the naive ones).
"""

from __future__ import annotations

import csv
import json
import math
import sys
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest

from membrane_bench.bench import BenchReport, Target
from membrane_bench.echo import EchoError, EchoServer, echo_bind_address, echo_reply_padding
from membrane_bench.loadtest import PERCENTILES, LoadError, LoadResult, LoadSpec, run_load
from membrane_cli.dispatcher import main

REPLY_BYTES = 1_700  # about a 20 x 20 float32 frame with its envelope


@pytest.fixture(scope="module")
def echo() -> Iterator[EchoServer]:
    with EchoServer("tcp://127.0.0.1:1", REPLY_BYTES) as server:
        yield server


def _check_percentiles(values: dict[str, float]) -> None:
    ordered = [values[label] for label in (*PERCENTILES, "max")]
    assert all(math.isfinite(v) and v >= 1 for v in ordered), values
    assert ordered == sorted(ordered), values


@pytest.mark.slow
def test_open_loop_sends_on_schedule_and_reports_every_field(echo: EchoServer) -> None:
    spec = LoadSpec(mode="open", rate=400, duration=0.5, warmup=0.1, times=(0.0, 0.5))
    result = run_load(echo.address, spec, "echo")
    # Requests are due every 2.5 ms: exactly 200 fall in the measured half second (on a busy
    # machine the client may fall behind: those it could not send in time are counted unsent).
    assert result.sent + result.unsent == 200
    assert result.replies == result.ok == result.sent > 0
    assert result.errors == {}
    assert isinstance(result.missed_deadlines, int)
    assert result.throughput == pytest.approx(result.replies / 0.5)
    _check_percentiles(result.percentiles("latency"))
    _check_percentiles(result.percentiles("service"))
    summary = result.summary()
    assert set(summary["latency_us"]) == {"p50", "p90", "p99", "p99.9", "max", "mean"}
    assert summary["error_count"] == 0


@pytest.mark.slow
def test_coordinated_omission_is_corrected_around_a_stall() -> None:
    """An echo that sleeps 200 ms once: 1 naive sample is slow, ~200 corrected ones are."""
    spec = LoadSpec(mode="open", rate=1000, duration=1.0, warmup=0.2)
    # Request 500 arrives 0.3 s into the measured second (200 warm-up requests come first).
    with EchoServer("tcp://127.0.0.1:1", 100, stall_at=500, stall_s=0.2) as stalled:
        result = run_load(stalled.address, spec, "stalled")
    corrected, naive = result.percentiles("latency"), result.percentiles("service")
    assert result.ok == result.sent == 1000 - result.unsent
    # Counted from due times, every request that fell due during the stall waited for it.
    assert corrected["p99"] >= 150_000
    assert result.missed_deadlines is not None and result.missed_deadlines >= 150
    # Send-to-receive timing sees one slow request only: its p99 hides the stall entirely.
    assert naive["max"] >= 200_000
    assert naive["p99"] < 100_000


@pytest.mark.slow
def test_requests_still_due_when_the_run_ends_are_counted_unsent() -> None:
    """A stall that outlasts the run: what fell due meanwhile was never sent, and says so."""
    spec = LoadSpec(mode="open", rate=100, duration=0.5, warmup=0.0, timeout=2.0)
    # Request 20 (due at 0.19 s) is answered 0.5 s later, after the run's end at 0.5 s.
    with EchoServer("tcp://127.0.0.1:1", 100, stall_at=20, stall_s=0.5) as stalled:
        result = run_load(stalled.address, spec, "stalled")
    assert result.sent == result.ok == 20
    assert result.unsent == 30
    assert result.missed_deadlines is not None and result.missed_deadlines >= 31
    assert result.summary()["unsent"] == 30


@pytest.mark.slow
def test_closed_loop_keeps_requests_in_flight_from_several_processes(echo: EchoServer) -> None:
    spec = LoadSpec(mode="closed", concurrency=3, clients=2, duration=0.5, warmup=0.1)
    assert [spec.in_flight(i) for i in range(2)] == [2, 1]
    result = run_load(echo.address, spec, "echo")
    assert result.replies == result.ok > 10
    assert result.missed_deadlines is None
    assert result.throughput == pytest.approx(result.replies / 0.5)
    _check_percentiles(result.percentiles())


@pytest.mark.slow
def test_requests_without_reply_count_as_timeouts_and_the_run_still_ends() -> None:
    spec = LoadSpec(mode="open", rate=50, duration=0.6, warmup=0.0, timeout=0.1)
    with EchoServer("tcp://127.0.0.1:1", 100, stall_at=3, stall_s=0.5) as stalled:
        result = run_load(stalled.address, spec, "stalled")
    assert result.errors.get("timeout", 0) >= 2
    assert result.late_replies >= 1  # the stalled replies arrive after their requests gave up
    assert result.ok + result.errors["timeout"] == result.sent == 30 - result.unsent


def test_error_replies_are_counted_by_code() -> None:
    """A server that answers every request with an error reply (a real REP socket)."""
    import threading

    import zmq

    context = zmq.Context()
    socket = context.socket(zmq.REP)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, 100)
    port = socket.bind_to_random_port("tcp://127.0.0.1")
    stop = threading.Event()

    def answer() -> None:
        while not stop.is_set():
            try:
                request = msgpack.unpackb(socket.recv())
            except zmq.Again:
                continue
            error = {"code": "out_of_domain", "message": "past the end"}
            socket.send(msgpack.packb({"v": 1, "id": request["id"], "ok": False, "error": error}))

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        spec = LoadSpec(mode="open", rate=100, duration=0.3, warmup=0.0)
        result = run_load(f"tcp://127.0.0.1:{port}", spec, "errors")
    finally:
        stop.set()
        thread.join(timeout=5)
        socket.close(linger=0)
        context.term()
    assert result.ok == 0
    assert result.errors == {"out_of_domain": result.sent}
    assert result.sent + result.unsent == 30


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"mode": "open", "rate": 0.0}, "rate"),
        ({"mode": "open", "rate": math.inf}, "rate"),
        ({"mode": "open", "rate": 10.0, "duration": -1.0}, "duration"),
        ({"mode": "open", "rate": 10.0, "clients": 0}, "clients"),
        ({"mode": "closed", "concurrency": 1, "clients": 2}, "concurrency"),
        ({"mode": "open", "rate": 10.0, "times": ()}, "times"),
        ({"mode": "open", "rate": 10.0, "times": (math.nan,)}, "finite"),
        ({"mode": "sideways", "rate": 10.0}, "mode"),
    ],
)
def test_a_bad_load_spec_is_refused_with_a_message(fields: dict, message: str) -> None:
    with pytest.raises(LoadError, match=message):
        LoadSpec(**fields)


def test_echo_replies_are_as_long_as_asked() -> None:
    for size in (30, 200, 255, 256, 300, 1_700, 70_000):
        packed = msgpack.packb({"v": 1, "id": 0, "ok": True, "payload": echo_reply_padding(size)})
        assert len(packed) == size


def test_echo_uses_the_targets_transport() -> None:
    assert echo_bind_address("tcp://127.0.0.1:5555") == "tcp://127.0.0.1:*"
    assert echo_bind_address("ipc:///tmp/membrane.ipc").startswith("ipc://")
    with pytest.raises(EchoError, match="tcp:// or ipc://"):
        echo_bind_address("inproc://membrane")


@pytest.mark.slow
def test_echo_over_ipc(tmp_path: Path) -> None:
    spec = LoadSpec(mode="closed", concurrency=1, duration=0.2, warmup=0.0)
    with EchoServer("ipc:///tmp/x.ipc", 64) as server:
        assert server.address.startswith("ipc://")
        result = run_load(server.address, spec, "echo")
    assert result.ok > 10


def _report(echo: EchoServer) -> BenchReport:
    spec = LoadSpec(mode="open", rate=200, duration=0.3, warmup=0.0, times=(0.0,))
    first = run_load(echo.address, spec, "server")
    second = run_load(echo.address, spec, "echo")
    target = Target(echo.address, "echo", (0.0,), REPLY_BYTES, None)
    return BenchReport(target=target, spec=spec, server=first, baseline=second)


@pytest.mark.slow
def test_report_ratios_table_json_and_csv(echo: EchoServer, tmp_path: Path) -> None:
    report = _report(echo)
    ratios = report.vs_baseline()
    assert ratios is not None
    ours, theirs = report.server.percentiles(), report.baseline.percentiles()  # type: ignore[union-attr]
    assert ratios["p99"] == pytest.approx(ours["p99"] / theirs["p99"])
    assert ratios["throughput"] == pytest.approx(
        report.baseline.throughput / report.server.throughput  # type: ignore[union-attr]
    )
    data = report.to_dict()
    assert data["config"]["rate_hz"] == 200
    assert data["baseline"]["replies"] + data["baseline"]["unsent"] == 60
    json.dumps(data)  # plain data only
    table = report.table()
    assert "server vs echo" in table and "p99.9" in table
    path = tmp_path / "bench.csv"
    report.write_csv(path)
    report.write_csv(path)  # appends without a second header
    rows = list(csv.DictReader(path.open()))
    assert [row["label"] for row in rows] == ["server", "echo", "server", "echo"]
    assert float(rows[0]["p99_vs_baseline"]) == pytest.approx(ratios["p99"])
    assert rows[1]["p99_vs_baseline"] == ""


@pytest.mark.slow
def test_a_report_without_baseline_has_no_ratios(echo: EchoServer) -> None:
    report = _report(echo)
    report.baseline = None
    assert report.vs_baseline() is None
    assert report.to_dict()["vs_baseline"] is None
    assert "server vs echo" not in report.table()


def test_merged_result_of_no_replies_has_nan_percentiles() -> None:
    spec = LoadSpec(mode="closed", concurrency=1, duration=1.0, warmup=0.0)
    empty = LoadResult.merge("x", "tcp://127.0.0.1:1", spec, [])
    assert math.isnan(empty.percentiles()["p99"])
    assert empty.throughput == 0.0


# ---- the command line -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "--rate", "0"],
        ["bench", "--rate", "nan"],
        ["bench", "--rate", "10", "--concurrency", "2"],
        ["bench", "--clients", "0"],
        ["bench", "--payload", "shout"],
        ["bench", "--duration", "-1"],
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_concurrency_below_clients_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["bench", "--concurrency", "1", "--clients", "2", "--connect", "tcp://127.0.0.1:1"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "concurrency" in err


def test_no_server_is_one_line_and_exit_1(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["bench", "--connect", "tcp://127.0.0.1:1", "--timeout", "0.1", "--quiet"])
    assert code == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no reply" in err


def test_without_the_bench_extra_it_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in ("membrane_bench.bench", "membrane_bench.loadtest"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    monkeypatch.setitem(sys.modules, "hdrh", None)  # makes `import hdrh` fail
    monkeypatch.setitem(sys.modules, "hdrh.histogram", None)
    code = main(["bench", "--connect", "tcp://127.0.0.1:1"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "pip install 'membrane-tissue[bench]'" in err and len(err.splitlines()) == 1


# ---- against a live server --------------------------------------------------------------------


@pytest.fixture(scope="module")
def rope_server_address() -> Iterator[str]:
    """A real server on a small exact-evaluator rope (20 points, 101 steps of 0.01 s)."""
    from membrane_server.scene import scene_from_dict
    from membrane_server.server import Server

    scene = scene_from_dict(
        {
            "name": "rope-small",
            "model": "string-forced",
            "evaluator": "exact",
            "lattice": {"nx": 20},
            "dt": 0.01,
            "duration": 1.0,
        }
    )
    with Server([scene], bind="tcp://127.0.0.1:*") as server:
        yield server.address


def test_probe_reads_the_scenes_time_grid(rope_server_address: str) -> None:
    from membrane_bench.bench import probe

    target = probe(rope_server_address)
    assert target.scene == "rope-small"
    assert target.evaluator == "exact"
    assert len(target.times) == 101
    assert target.times[:3] == (0.0, 0.01, 0.02)
    assert target.times[-1] == pytest.approx(1.0)
    assert target.reply_bytes > 20 * 4  # 20 float32 displacements and the envelope


@pytest.mark.slow
def test_bench_against_a_live_server_with_baseline_produces_every_field(
    rope_server_address: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv_path = tmp_path / "bench.csv"
    argv = ["bench", "--connect", rope_server_address, "--rate", "200", "--duration", "1"]
    argv += ["--warmup", "0.2", "--baseline", "--json", "--csv", str(csv_path), "--quiet"]
    code = main(argv)
    out = capsys.readouterr().out
    data = json.loads(out)
    assert set(data) == {"config", "server", "baseline", "vs_baseline"}
    assert data["config"]["query_times"] == 101
    assert data["config"]["scene"] == "rope-small"
    assert data["config"]["deadline_ms"] == pytest.approx(5.0)
    for run in ("server", "baseline"):
        result = data[run]
        assert result["sent"] + result["unsent"] == 200
        assert result["ok"] == result["sent"]
        assert result["errors"] == {}
        assert result["throughput_hz"] > 0
        latency = [result["latency_us"][k] for k in ("p50", "p90", "p99", "p99.9", "max")]
        assert latency == sorted(latency) and latency[0] >= 1
    assert set(data["vs_baseline"]) == {"p50", "p90", "p99", "p99.9", "max", "throughput"}
    assert data["vs_baseline"]["p99"] == pytest.approx(
        data["server"]["latency_us"]["p99"] / data["baseline"]["latency_us"]["p99"]
    )
    assert code == (1 if data["server"]["unsent"] else 0)
    rows = list(csv.DictReader(csv_path.open()))
    assert [row["label"] for row in rows] == ["server", "echo"]


@pytest.mark.slow
def test_bench_closed_loop_against_a_live_server_prints_a_table(
    rope_server_address: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["bench", "--connect", rope_server_address, "--concurrency", "2", "--clients", "2"]
    code = main([*argv, "--duration", "0.5", "--warmup", "0", "--payload", "ping", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    assert "closed loop 2 in flight, 2 clients" in out
    assert "server (us)" in out and "echo" not in out


def test_bench_reports_error_replies_by_code(
    rope_server_address: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["bench", "--connect", rope_server_address, "--scene", "no-such-scene", "--quiet"]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert "unknown_scene" in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_baseline_in_alternating_segments_merges_every_part(rope_server_address: str) -> None:
    from membrane_bench.bench import probe, run_bench

    spec = LoadSpec(mode="open", rate=200, duration=0.6, warmup=0.1)
    report = run_bench(probe(rope_server_address), spec, baseline=True, segments=2)
    assert report.baseline is not None
    for result in (report.server, report.baseline):
        assert result.sent + result.unsent == 120  # two parts of 0.3 s at 200 Hz
        assert result.latency.get_total_count() == result.replies == result.ok
        assert result.throughput == pytest.approx(result.replies / 0.6)
    assert report.config()["segments"] == 2
    assert "in 2 parts alternating with the echo" in report.table()


def _bench_stderr(address: str, on_terminal: bool) -> str:
    """stderr of a real `membrane bench` run, written to a pipe or to a pseudo-terminal."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import termios

    command = [sys.executable, "-m", "membrane_cli", "bench", "--connect", address,
               "--rate", "100", "--duration", "0.4", "--warmup", "0",
               "--payload", "ping"]  # fmt: skip
    if not on_terminal:
        result = subprocess.run(command, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr
        return result.stderr
    controller, terminal = pty.openpty()
    # A fresh pseudo-terminal is 0 x 0; tqdm draws nothing that narrow. 24 rows, 80 columns:
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    with subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=terminal) as process:
        os.close(terminal)
        chunks = []
        while True:
            try:
                chunk = os.read(controller, 4096)
            except OSError:  # EIO: the terminal's last writer has exited
                break
            if not chunk:
                break
            chunks.append(chunk)
        assert process.wait(timeout=60) == 0
    os.close(controller)
    return b"".join(chunks).decode(errors="replace")


@pytest.mark.slow
def test_progress_bar_shows_on_a_terminal_only(rope_server_address: str) -> None:
    assert "\r" in _bench_stderr(rope_server_address, on_terminal=True)  # the bar, redrawn in place
    piped = _bench_stderr(rope_server_address, on_terminal=False)
    assert "\r" not in piped and "replies" not in piped, piped


@pytest.mark.slow
def test_a_live_step_presses_a_tool_where_the_engine_takes_tools_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from membrane_bench.bench import probe
    from membrane_server.served import ServedScene
    from membrane_server.server import Server

    monkeypatch.setenv("MEMBRANE_CACHE_DIR", str(tmp_path / "cache"))
    scene = ServedScene.load("skin-patch-nonlinear")  # the fem-nonlinear engine: tools only
    with Server([scene], bind="tcp://127.0.0.1:*") as server:
        target = probe(server.address, payload="step")
        assert target.press == "tool"
        assert target.probe_at == pytest.approx((0.025, 0.025))  # the middle, in m
        assert target.probe_radius == pytest.approx(0.005)  # a tenth of the patch
        argv = ["bench", "--connect", server.address, "--payload", "step", "--rate", "100"]
        code = main([*argv, "--duration", "0.5", "--warmup", "0.1", "--json", "--quiet"])
    data = json.loads(capsys.readouterr().out)
    assert data["server"]["errors"] == {} and data["server"]["ok"] == data["server"]["sent"] > 0
    assert code in (0, 1)  # 1 only when a request could not be sent in time
