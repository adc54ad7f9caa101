"""Attacks on the serving loop: what floods, stalls or bloats the server rather than one request.

Each slow test runs `membrane serve` in its own process (attackers.WatchedServer: RSS sampled,
a watchdog at 1.5 GiB) with a good client stepping its own live session at 200 Hz all along
(live_good_client): undisturbed, during the attack, undisturbed again, on the same server.
Each ends with: the server alive, its RSS growth within the stated bound, no traceback in the
log (but the one a test asks for), refusals as structured errors, and the good client's figures
compared with its undisturbed runs (no failure, no stall; its deadline misses are judged by
benchmarks/attack_deadlines.py). The figures are printed (docs/ROBUSTNESS.md, "Attacks", rows
S1-S5, quotes them). Loopback only; every loop is bounded.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import pytest
from attackers import (
    FAULT_MARK,
    FAULTY_MEMBRANE,
    MiB,
    WatchedServer,
    in_child,
    silent_dealers,
)
from live_good_client import LiveGoodClient, LiveRun, check_against_undisturbed
from reporting import print_past_capture

from membrane_client import Client
from membrane_client.errors import ServerError
from membrane_client.protocol import Request
from membrane_server.log_output import LogOutput

LIVE = "membrane-live"  # the good client's scene
BIG = "skin-100"  # a 100 x 100 live scene: its describe is 164 KB, a float64 frame 80 KB
UNDISTURBED_S = 0.8
MESSAGE_CHARS = 300  # the longest error message a reply may carry
MEASURED: list[str] = []


@pytest.fixture(scope="module", autouse=True)
def _report_measured(request: pytest.FixtureRequest) -> Iterator[None]:
    yield
    if MEASURED:
        print_past_capture(request, "\nserver-loop attacks: " + "; ".join(MEASURED))


def _big_scene(path: Path, description: str = "100 x 100, live", duration: float = 0.1) -> str:
    path.write_text(
        f'name = "{BIG}"\ndescription = "{description}"\nmodel = "membrane-forced"\n'
        f'evaluator = "exact"\ndt = 0.001\nduration = {duration}\npolicy = "hold"\n'
        "[lattice]\nnx = 100\nny = 100\n[live]\ndamping = 0.02\n"
    )
    return str(path)


def _start(
    watched: list[WatchedServer], scenes: list[str], extra: list[str] | None = None, **kwargs: Any
) -> WatchedServer:
    server = WatchedServer(scenes, extra, **kwargs)
    watched.append(server)
    return server


def _survived(
    request: pytest.FixtureRequest,
    server: WatchedServer,
    good: LiveGoodClient,
    undisturbed: LiveRun,
    bound: int,
    attack: str,
    tracebacks: int = 0,
) -> None:
    """Alive, a good request answered, RSS growth since listening within ``bound``,
    ``tracebacks`` tracebacks in the log, and the good client never failed nor stalled (its
    deadlines beside those undisturbed, before and after: ``check_against_undisturbed``)."""
    during = good.begin("undisturbed after")
    time.sleep(UNDISTURBED_S)
    after = good.stop()
    growth = server.growth()
    MEASURED.append(f"{attack}: RSS +{growth / MiB:.1f} MiB (bound {bound / MiB:.0f})")
    assert not server.killed_for_memory, f"RSS passed the watchdog: {server.peak / MiB:.0f} MiB"
    assert server.alive, server.log[-20:]
    with Client(server.address, timeout=5.0) as client:
        client.ping()
    assert growth < bound, f"RSS grew {growth / MiB:.1f} MiB"
    assert len(server.tracebacks()) == tracebacks, server.log[-40:]
    check_against_undisturbed(request, attack, undisturbed, during, after)


def _stats(server: WatchedServer) -> dict[str, Any]:
    with Client(server.address, timeout=5.0) as client:
        return client.request("stats")


# -- S5. a client that reads every reply loses none when it pipelines ----------------------------


@pytest.mark.slow
def test_a_pipelining_client_that_reads_loses_no_reply(
    request: pytest.FixtureRequest, watched: list[WatchedServer], tmp_path: Path
) -> None:
    """With a 100 x 100 scene hosted, the send queue held 6 replies per peer (the budget over
    the largest describe): 10,000 pings 8 in flight lost 37, the client reading all along. Now
    the queue holds at least twice the in-flight limit the server states, never fewer than a
    1 kHz session over 10 ms needs, and a queue that looks full is read again before a drop."""
    server = _start(watched, [LIVE, _big_scene(tmp_path / "skin.toml")])
    good = LiveGoodClient(server.address).start()
    undisturbed = good.measure(UNDISTURBED_S)
    peers = _stats(server).get("peers", {})
    with Client(server.address, timeout=5.0) as client:
        limits = client.request("hello")["limits"]
    # hello states it (the dispatcher's); the server's own figures say the same.
    in_flight = int(limits.get("max_in_flight", peers.get("max_in_flight", 16)))
    assert in_flight >= 10  # a session at membrane-live's 1 kHz pipelining over 10 ms
    good.begin("pipelining")
    ping = Request("ping", 1).to_wire().hex()
    loop = in_child("request_loop", address=server.address, payload_hex=ping, count=10_000,
                    in_flight=in_flight)  # fmt: skip
    dropped = _stats(server)["dropped_replies"]
    MEASURED.append(
        f"10,000 pings {in_flight} in flight: {loop['answered']} answered, dropped {dropped}"
    )
    assert loop["answered"] == 10_000 and loop["codes"] == {"ok": 10_000}, (loop, dropped)
    assert dropped == {}, dropped
    _survived(request, server, good, undisturbed, 32 * MiB, "pipelined pings")


# -- S1. freed memory handed back while clients are active --------------------------------------


@pytest.mark.slow
def test_memory_freed_by_peers_that_leave_is_handed_back_under_load(
    request: pytest.FixtureRequest, watched: list[WatchedServer], tmp_path: Path
) -> None:
    """malloc_trim ran only after 50 ms with no request, so under any client at 20 Hz or more
    the RSS stayed at its peak (1,605 MiB with a 100 Hz client). Now memory is handed back on
    a schedule, between requests: within 32 MiB of the baseline within 2 s of the peak.

    The peak: 8 peers with a budget of 16 MiB each ask for 100 describes of a 100 x 100 scene
    (164 KB each) and never read, while a reading client asks for frames not asked for before
    (cached replies, which stay: the freed memory lies below them, where only a trim reaches).
    """
    budget = 16 * MiB
    server = _start(
        watched, [LIVE, _big_scene(tmp_path / "skin.toml")], ["--peer-budget", str(budget)]
    )
    good = LiveGoodClient(server.address).start()
    undisturbed = good.measure(UNDISTURBED_S)
    baseline = server.rss()
    server.reset_peak()
    good.begin("peers that never read, then leave")
    peers = silent_dealers(server.address, 8)
    describe = Request("describe", 1, scene=BIG).to_wire()
    reader = Client(server.address, timeout=5.0)
    try:
        for sent in range(800):  # paced: the peak, not a flood, is the attack here
            peers[sent % 8].send_multipart([b"", describe])
            if sent % 4 == 3:
                time.sleep(0.005)
            if sent % 50 == 0:
                reader.request("query", scene=BIG, t=(10 + sent // 50) * 0.001, dtype="<f8")
        deadline = time.monotonic() + 10.0
        while _stats(server)["requests"] < 800 + 16 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)
        peak = server.peak
    finally:
        reader.close()
        for peer in peers:
            peer.close()
    left = time.perf_counter()
    back_after = None
    while time.perf_counter() - left < 3.0:
        if server.rss() <= baseline + 32 * MiB:
            back_after = time.perf_counter() - left
            break
        time.sleep(0.02)
    memory = _stats(server).get("memory", {})
    MEASURED.append(
        f"8 silent peers x 100 describes of 100 x 100 (budget 16 MiB): peak "
        f"+{(peak - baseline) / MiB:.0f} MiB; within 32 MiB of the baseline "
        f"{'never' if back_after is None else f'{back_after:.2f} s'} after they left; trims "
        f"{memory.get('trims')} (longest {memory.get('max_trim_ms', 0):.1f} ms)"
    )
    assert peak - baseline > 64 * MiB  # the attack did make a peak
    assert back_after is not None and back_after < 2.0, (server.rss() - baseline) / MiB
    # 8 peers x (16 MiB + one reply), and the frames cached.
    _survived(request, server, good, undisturbed, 8 * (budget + MiB) + 32 * MiB, "memory back")


# -- S2. reloads free the scenes they swap out ---------------------------------------------------


@pytest.mark.slow
def test_reloads_hold_a_bounded_number_of_old_scenes(
    request: pytest.FixtureRequest, watched: list[WatchedServer], tmp_path: Path
) -> None:
    """Every SIGHUP kept the previous scenes until a full garbage collection (the old
    dispatcher in a reference cycle): +83 MiB per reload of a 100 x 100 scene. Now an old scene
    is freed as soon as no session holds it, and at most 4 held ones are kept: past that the
    oldest one's sessions are closed. Here a session is left open on each of 7 revisions."""
    scene = tmp_path / "skin.toml"
    _big_scene(scene, "revision 0", duration=0.5)
    server = _start(watched, [LIVE, str(scene)])
    good = LiveGoodClient(server.address).start()
    undisturbed = good.measure(UNDISTURBED_S)
    good.begin("7 reloads")
    clients = [Client(server.address, timeout=5.0) for _ in range(7)]
    try:
        sessions = []
        for reload in range(1, 8):
            sessions.append(clients[reload - 1].session(BIG))  # held on this revision
            _big_scene(scene, f"revision {reload}", duration=0.5)
            server.process.send_signal(signal.SIGHUP)
            deadline = time.monotonic() + 30.0
            while sum("reloaded scenes" in line for line in server.log) < reload:
                assert time.monotonic() < deadline and server.alive, server.log[-10:]
                time.sleep(0.05)
        one_revision = _revision_bytes(server)
        # The current revision and 4 held ones, and what building the next one takes.
        bound = 6 * one_revision + 48 * MiB
        assert server.growth() < bound, (server.growth() / MiB, one_revision / MiB)
        held = _stats(server).get("reloads", {})
        with pytest.raises(ServerError) as refused:
            sessions[0].step()  # the oldest revision's session was closed past the bound
        assert refused.value.code == "unknown_session"
        assert len(str(refused.value)) < MESSAGE_CHARS + 40
        assert sessions[-1].step().k == 1  # the latest is held
        sessions[0].closed = True  # the server closed it
        for session in sessions:
            session.close()
        deadline = time.monotonic() + 2.0
        while _stats(server)["reloads"]["revisions_held"] and time.monotonic() < deadline:
            time.sleep(0.05)
        after = _stats(server)["reloads"]
    finally:
        for client in clients:
            client.close()
    MEASURED.append(
        f"7 reloads with a session on each revision: {held}; once closed {after}; peak RSS "
        f"+{server.growth() / MiB:.0f} MiB, a revision {one_revision / MiB:.0f} MiB"
    )
    assert held["revisions_held"] == 4 and held["sessions_closed"] >= 3, held
    assert after["revisions_held"] == 0, after
    _survived(request, server, good, undisturbed, bound, "7 reloads")


def _revision_bytes(server: WatchedServer) -> int:
    """What one revision of the big scene holds: its evaluator and its live engine."""
    with Client(server.address, timeout=5.0) as client:
        info = client.request("describe", scene=BIG)
    evaluator, live = info["evaluator"], info["live"]
    return int(evaluator.get("memory_bytes", 0)) + int(live.get("session_bytes", 0))


# -- S3. a request that makes the server log cannot flood the log -------------------------------


@pytest.mark.slow
def test_a_flood_of_failing_requests_writes_a_bounded_log(
    request: pytest.FixtureRequest, watched: list[WatchedServer]
) -> None:
    """Each internal error logged a 1.3 KB traceback: one client wrote 1.76 MB/s of log (20,000
    requests: 25.8 MB). Now a traceback of one kind is written once, lines of one kind at most
    10 a second, and the rest are counted. The requests carry a fault the test injects."""
    server = _start(watched, [LIVE], membrane=FAULTY_MEMBRANE)
    good = LiveGoodClient(server.address).start()
    undisturbed = good.measure(UNDISTURBED_S)
    before = server.log_bytes
    good.begin("20,000 failing requests")
    faulty = msgpack.packb({"v": 1, "id": 1, "op": "ping", "fault": FAULT_MARK}).hex()
    started = time.perf_counter()
    loop = in_child("request_loop", address=server.address, payload_hex=faulty, count=20_000,
                    in_flight=16)  # fmt: skip
    took = time.perf_counter() - started
    deadline = time.monotonic() + 3.0  # the writer tells the suppressions once a second
    while not any("suppressed" in line for line in server.log) and time.monotonic() < deadline:
        time.sleep(0.05)
    written = server.log_bytes - before
    assert written < 64 * 1024, f"{written:,} bytes of log"
    log = _stats(server).get("log", {})
    MEASURED.append(f"20,000 failing requests in {took:.1f} s: {written:,} bytes of log, {log}")
    assert loop["codes"] == {"internal_error": 20_000}, loop
    assert loop["longest_message"] <= MESSAGE_CHARS, loop
    assert log["suppressed"] > 15_000, log
    assert any("suppressed" in line for line in server.log), server.log[-10:]
    # The bug's traceback, once in full (then one line per shown occurrence).
    _survived(request, server, good, undisturbed, 32 * MiB, "failing requests", tracebacks=1)


# -- S4. a log output nobody reads does not stall serving ----------------------------------------


@pytest.mark.slow
def test_a_stderr_pipe_nobody_reads_does_not_stall_serving(
    request: pytest.FixtureRequest, watched: list[WatchedServer]
) -> None:
    """With stderr a pipe nobody drains, 48 traceback-logging requests stalled the server for
    every client until the pipe was read. Now lines wait in a bounded queue that a writer
    thread drains (dropped and counted when full): serving never waits for the log. The pipe
    here is a page (4 KiB): the startup lines nearly fill it."""
    server = _start(
        watched, [LIVE], membrane=FAULTY_MEMBRANE, read_stderr=False, stderr_pipe_bytes=4096
    )
    good = LiveGoodClient(server.address).start()
    undisturbed = good.measure(UNDISTURBED_S)
    good.begin("failing requests, stderr unread")
    faulty = msgpack.packb({"v": 1, "id": 1, "op": "ping", "fault": FAULT_MARK}).hex()
    loop = in_child("request_loop", address=server.address, payload_hex=faulty,
                    count=100_000, seconds=2.0, pause_s=0.002, timeout_ms=3000)  # fmt: skip
    answered = loop["answered"]
    assert not loop["stalled"] and loop["codes"] == {"internal_error": answered}, loop
    assert answered > 200, f"{answered} failing requests answered: the server stalled"
    log = _stats(server)["log"]
    MEASURED.append(f"stderr unread: {answered} failing requests answered in 2 s; log {log}")
    assert log["queued"] > 0 or log["dropped"] > 0, log
    server.read_stderr()
    deadline = time.monotonic() + 5.0
    while not any("suppressed" in line for line in server.log) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert any("suppressed" in line for line in server.log), server.log[-10:]
    _survived(request, server, good, undisturbed, 32 * MiB, "stderr unread", tracebacks=1)


# -- the log output itself -------------------------------------------------------------------


def _pipe_nobody_reads() -> tuple[int, int]:
    import fcntl

    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)
    return read_end, write_end


def _read_all(fd: int, quiet_s: float = 0.3) -> bytes:
    os.set_blocking(fd, False)
    data, last = b"", time.monotonic()
    while time.monotonic() - last < quiet_s:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            time.sleep(0.01)
            continue
        data, last = data + chunk, time.monotonic()
    return data


def _logger(output: LogOutput, name: str) -> logging.Logger:
    output.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    log = logging.getLogger(name)
    log.handlers, log.propagate = [output], False
    log.setLevel(logging.INFO)
    return log


def test_a_full_output_drops_lines_and_counts_them_never_blocks() -> None:
    read_end, write_end = _pipe_nobody_reads()
    output = LogOutput(write_end, per_kind=10_000, overall=10_000, max_queued_lines=50)
    log = _logger(output, "membrane-test.full")
    try:
        slowest = 0.0
        for k in range(3000):  # distinct kinds: none suppressed, the queue fills
            started = time.perf_counter()
            log.warning(f"line {k} " + "x" * 100)
            slowest = max(slowest, time.perf_counter() - started)
        assert slowest < 0.05  # a blocked output would hold the caller here forever
        counts = output.snapshot()
        assert counts["dropped"] > 2000 and counts["queued"] <= 50, counts
        text = _read_all(read_end).decode()
        assert "line 0 " in text
        assert "log lines dropped: the log output did not keep up" in text
    finally:
        output.close()
        os.close(read_end)
        os.close(write_end)


@pytest.mark.slow
def test_lines_of_one_kind_are_rate_limited_and_tracebacks_shortened() -> None:
    read_end, write_end = os.pipe()
    now = [0.0]
    output = LogOutput(write_end, per_kind=3, overall=100, clock=lambda: now[0])
    log = _logger(output, "membrane-test.rate")
    try:
        for k in range(50):
            try:
                raise ValueError(f"bad input {k}")
            except ValueError:
                log.exception("answering %s failed", k)  # the argument never makes a kind
        now[0] = 1.5  # the next window: suppressions are told, the kind may write again
        time.sleep(0.6)  # the writer looks a few times a window
        log.error("answering %s failed", "again")
        assert output.drain(2.0)
        text = _read_all(read_end).decode()
    finally:
        output.close()
        os.close(read_end)
        os.close(write_end)
    assert text.count("Traceback") == 1, text
    assert "answering 1 failed [ValueError: bad input 1; its traceback as written at" in text
    assert "answering 3 failed" not in text
    assert "47 more lines like 'answering %s failed' suppressed" in text, text
    assert "answering again failed" in text
    counts = output.snapshot()
    assert counts["suppressed"] == 47 and counts["tracebacks_shortened"] == 2, counts


def test_stats_count_the_log_lines() -> None:
    from membrane_server.stats import Stats

    assert set(Stats().snapshot()["log"]) == {
        "written", "dropped", "suppressed", "tracebacks_shortened", "failed", "queued",
    }  # fmt: skip


def test_the_send_queue_holds_twice_the_in_flight_limit() -> None:
    from membrane_server.server import DEFAULT_IN_FLIGHT, max_in_flight, send_high_water_mark

    class Served:  # what max_in_flight reads of a served scene
        def __init__(self, dt: float, live: bool) -> None:
            self.scene, self.live = type("Scene", (), {"dt": dt})(), object() if live else None

    budget = 1024 * 1024
    film, live_1khz = Served(0.01, False), Served(0.001, True)
    # A 100 x 100 live scene's 168 KB describe: the old queue held 6; a 1 kHz session over
    # 10 ms needs 10 in flight, so the queue holds 20 (3.4 MB for a peer that never reads).
    assert max_in_flight([live_1khz], budget, 168_000) == 10  # type: ignore[list-item]
    assert send_high_water_mark(budget, 168_000, 10) == 20
    # The built-in 20 x 20 scenes: small replies, as many as fit the budget.
    assert max_in_flight([film], budget, 15_000) == DEFAULT_IN_FLIGHT  # type: ignore[list-item]
    assert send_high_water_mark(budget, 15_000, DEFAULT_IN_FLIGHT) == 69
    # A 65,536-point film: two 530 KB replies, as before (1 in flight).
    assert max_in_flight([film], budget, 530_000) == 1  # type: ignore[list-item]
    assert send_high_water_mark(budget, 530_000, 1) == 2


def test_memory_is_handed_back_once_freed_and_when_no_request_waits() -> None:
    from membrane_server.server import MemoryRelease

    trims: list[int] = []
    rss = [100 * MiB]

    def trim(pad: int) -> int:
        trims.append(pad)
        rss[0] = 100 * MiB
        return 1

    memory = MemoryRelease(trim=trim, rss=lambda: rss[0])
    now = 1000.0
    assert not memory.tick(now, idle=False, requests=1)  # nothing freed: no walk of the heap
    memory.arm()  # a peer left
    assert memory.tick(now + 0.1, idle=False, requests=2)
    memory.arm()
    assert not memory.tick(now + 0.3, idle=False, requests=3)  # at most every 0.5 s
    assert not memory.tick(now + 0.7, idle=False, requests=4, queued=True)  # a request waits
    assert memory.tick(now + 0.75, idle=False, requests=5)  # the queue emptied
    memory.arm()
    assert not memory.tick(now + 1.4, idle=False, requests=6, queued=True)
    assert memory.tick(now + 2.5, idle=False, requests=7, queued=True)  # waited 1 s: trims
    rss[0] = 200 * MiB  # grown, nothing known freed: only every 10 s
    assert not memory.tick(now + 5.0, idle=False, requests=8)
    assert memory.tick(now + 13.0, idle=False, requests=9)
    assert memory.tick(now + 19.0, idle=True, requests=10)  # idle after serving: every 5 s
    assert not memory.tick(now + 25.0, idle=True, requests=10)  # no request since
    assert len(trims) == 5 and memory.snapshot()["trims"] == 5
    assert memory.snapshot()["released_bytes"] == 100 * MiB


def test_installing_the_output_replaces_only_what_writes_to_stderr() -> None:
    import io

    from membrane_server.log_output import install, installed

    root = logging.getLogger()
    saved, saved_warnings = list(root.handlers), logging.getLogger("py.warnings").handlers
    other = logging.StreamHandler(io.StringIO())  # a handler elsewhere (a test's capture)
    to_stderr = logging.StreamHandler(sys.stderr)
    read_end, write_end = os.pipe()
    try:
        root.handlers = [other, to_stderr]
        assert install(io.StringIO()) is None  # no descriptor: nothing changed
        assert root.handlers == [other, to_stderr]
        output = install(write_end)
        assert output is not None and installed() is output
        assert root.handlers == [other, output]
        output.close()
    finally:
        root.handlers = saved
        logging.captureWarnings(False)
        logging.getLogger("py.warnings").handlers = saved_warnings
        os.close(read_end)
        os.close(write_end)
