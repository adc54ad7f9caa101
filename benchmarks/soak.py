"""Soak: a `membrane serve` process under a steady 1 kHz load for a minute, watched for leaks.

Starts `membrane serve --scene SCENE` on a free loopback port, then `membrane bench` at
``--rate`` in total from ``--clients`` processes for ``--duration`` seconds (open loop: every
request is due at a fixed time). Meanwhile the server's resident memory (VmRSS in
/proc/PID/status) is sampled every half second. Then the server is stopped with SIGTERM.

Passes (exit code 0) when:

- no request failed (no error reply, no timeout) and every request sent got its reply;
- the server's RSS at the end of the load is within ``--rss-tolerance`` (5 %) of its RSS at the
  start of the load (``--settle`` seconds after the load began: the first requests allocate
  connection buffers and caches once);
- the server exits 0 on SIGTERM.

Prints a markdown summary (the one in docs/ROBUSTNESS.md); ``--json FILE`` writes every figure.

    python benchmarks/soak.py [--scene membrane] [--rate 1000] [--clients 4] [--duration 60]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Any

from membrane_client import Client

logger = logging.getLogger("benchmarks.soak")

MEMBRANE = [sys.executable, "-m", "membrane_cli"]
SAMPLE_EVERY_S = 0.5
START_TIMEOUT_S = 120.0


class RssSampler:
    """Samples a process's VmRSS (KiB) in a background thread: (seconds since start, KiB)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.samples: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._started = 0.0

    def start(self) -> None:
        self._started = time.monotonic()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            rss = rss_kib(self.pid)
            if rss is None:
                return
            self.samples.append((time.monotonic() - self._started, rss))
            self._stop.wait(SAMPLE_EVERY_S)

    def at(self, seconds: float) -> int:
        """The first sample taken at or after ``seconds`` (the last one if none is)."""
        for when, rss in self.samples:
            if when >= seconds:
                return rss
        return self.samples[-1][1]


def rss_kib(pid: int) -> int | None:
    """VmRSS of a live process in KiB, or None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    for line in status.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return None


def start_server(scene: str, log: IO[bytes]) -> tuple[subprocess.Popen[str], str]:
    """`membrane serve` on a free loopback port (stderr to ``log``); returns it and its address."""
    process = subprocess.Popen(
        [*MEMBRANE, "serve", "--scene", scene, "--bind", "tcp://127.0.0.1:*"],
        stdout=subprocess.PIPE,
        stderr=log,
        text=True,
    )
    assert process.stdout is not None
    line = _read_line(process.stdout, START_TIMEOUT_S)
    if "listening on " not in line:
        process.kill()
        raise RuntimeError(f"the server did not start: {line!r}")
    return process, line.split("listening on ", 1)[1].split()[0]


def _read_line(stream: IO[str], timeout: float) -> str:
    result: list[str] = []
    reader = threading.Thread(target=lambda: result.append(stream.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    return result[0] if result else ""


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "kernel": platform.release(),
        "load_average": os.getloadavg(),
    }


def run_soak(args: argparse.Namespace) -> dict[str, Any]:
    """Run the soak once; returns every figure (see the module docstring)."""
    where = machine()  # the load average before the load
    with tempfile.TemporaryFile() as log:
        result = _soak(args, log)
        log.seek(0)
        server_log = log.read().decode(errors="replace").strip().splitlines()
    result["machine"] = where
    result["server_log"] = server_log[-20:]
    return result


def _soak(args: argparse.Namespace, log: IO[bytes]) -> dict[str, Any]:
    server, address = start_server(args.scene, log)
    sampler = RssSampler(server.pid)
    idle_rss = rss_kib(server.pid)
    logger.info("server pid %d on %s, idle RSS %s KiB", server.pid, address, idle_rss)
    bench_command = [
        *MEMBRANE, "bench", "--connect", address, "--rate", str(args.rate),
        "--clients", str(args.clients), "--duration", str(args.duration), "--json", "--quiet",
    ]  # fmt: skip
    try:
        sampler.start()
        logger.info("load: %s", " ".join(bench_command[2:]))
        started = time.monotonic()
        bench = subprocess.run(
            bench_command, capture_output=True, text=True, timeout=args.duration + 120
        )
        load_seconds = time.monotonic() - started
        sampler.stop()
        with Client(address, timeout=5.0) as client:
            stats = client.stats()
    finally:
        sampler.stop()
        server.send_signal(signal.SIGTERM)
        try:
            exit_code = server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
            exit_code = server.wait()
    if bench.returncode not in (0, 1) or not bench.stdout.strip():
        raise RuntimeError(f"membrane bench failed ({bench.returncode}): {bench.stderr.strip()}")
    report = json.loads(bench.stdout)["server"]
    rss_start = sampler.at(args.settle)
    rss_end = sampler.samples[-1][1]
    growth = (rss_end - rss_start) / rss_start
    return {
        "command": " ".join(["python", "benchmarks/soak.py", *sys.argv[1:]]),
        "bench_command": "membrane " + " ".join(bench_command[3:]),
        "scene": args.scene,
        "load_seconds": round(load_seconds, 1),
        "sent": report["sent"],
        "replies": report["replies"],
        "ok": report["ok"],
        "errors": report["errors"],
        "unsent": report["unsent"],
        "missed_deadlines": report["missed_deadlines"],
        "deadline_ms": json.loads(bench.stdout)["config"]["deadline_ms"],
        "latency_us": report["latency_us"],
        "throughput_hz": report["throughput_hz"],
        "server_requests": stats.requests,
        "server_errors": stats.errors,
        "rss_kib": {
            "idle": idle_rss,
            "start": rss_start,
            "end": rss_end,
            "max": max(rss for _, rss in sampler.samples),
            "trend_kib_per_min": _trend(sampler.samples, args.settle),
            "samples": [[round(when, 2), rss] for when, rss in sampler.samples],
        },
        "rss_growth": growth,
        "server_exit_code": exit_code,
    }


def _trend(samples: list[tuple[float, int]], after: float) -> float:
    """Least-squares slope of RSS against time after ``after`` seconds, KiB per minute."""
    points = [(when, rss) for when, rss in samples if when >= after]
    if len(points) < 2:
        return 0.0
    mean_t = sum(when for when, _ in points) / len(points)
    mean_rss = sum(rss for _, rss in points) / len(points)
    spread = sum((when - mean_t) ** 2 for when, _ in points)
    slope = sum((when - mean_t) * (rss - mean_rss) for when, rss in points) / spread
    return 60.0 * slope


def verdict(result: dict[str, Any], tolerance: float) -> list[str]:
    """The criteria that failed (empty: the soak passed)."""
    failed = []
    if result["errors"] or result["server_errors"]:
        failed.append(f"errors: client {result['errors']}, server {result['server_errors']}")
    # "unsent" (a request due in the last instants while its client still awaited the previous
    # reply) is reported, not failed: no reply is missing for a request that never left.
    if result["replies"] != result["sent"]:
        failed.append(f"missed replies: {result['sent'] - result['replies']} of {result['sent']}")
    if abs(result["rss_growth"]) > tolerance:
        failed.append(f"RSS changed by {result['rss_growth']:+.1%} (limit {tolerance:.0%})")
    if result["server_exit_code"] != 0:
        failed.append(f"the server exited {result['server_exit_code']} on SIGTERM")
    return failed


def markdown(result: dict[str, Any], failed: list[str]) -> str:
    """The summary table."""
    rss, latency = result["rss_kib"], result["latency_us"]
    rows = [
        ("requests sent / replies / ok",
         f"{result['sent']} / {result['replies']} / {result['ok']}"),
        ("errors (client, server)", f"{result['errors'] or 0}, {result['server_errors'] or 0}"),
        ("unsent (due at the very end)", str(result["unsent"])),
        ("throughput", f"{result['throughput_hz']:.1f} Hz"),
        ("latency p50 / p99 / p99.9 / max",
         f"{latency['p50']:.0f} / {latency['p99']:.0f} / {latency['p99.9']:.0f} / "
         f"{latency['max']:.0f} us"),
        (f"replies later than {result['deadline_ms']:g} ms", str(result["missed_deadlines"])),
        ("server RSS idle / start / end / max",
         f"{rss['idle']} / {rss['start']} / {rss['end']} / {rss['max']} KiB"),
        ("RSS end vs start", f"{result['rss_growth']:+.2%}"),
        ("RSS trend after the start", f"{rss['trend_kib_per_min']:+.0f} KiB/min"),
        ("server exit on SIGTERM", str(result["server_exit_code"])),
        ("verdict", "pass" if not failed else "FAIL: " + "; ".join(failed)),
    ]  # fmt: skip
    lines = ["| quantity | value |", "| --- | --- |"]
    lines += [f"| {name} | {value} |" for name, value in rows]
    return "\n".join(lines)


def main() -> int:
    """Run the soak; exit code 0 when it passes."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="membrane", help="scene to serve (default membrane)")
    parser.add_argument("--rate", type=float, default=1000.0, help="total requests per second")
    parser.add_argument("--clients", type=int, default=4, help="client processes (default 4)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load")
    parser.add_argument(
        "--settle", type=float, default=5.0, help="seconds into the load for the start RSS"
    )
    parser.add_argument(
        "--rss-tolerance", type=float, default=0.05, help="allowed RSS change (default 0.05)"
    )
    parser.add_argument("--json", type=Path, metavar="FILE", help="write every figure here")
    args = parser.parse_args()
    if not 0 <= args.settle < args.duration:
        parser.error("--settle must lie within the load's duration")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    result = run_soak(args)
    failed = verdict(result, args.rss_tolerance)
    result["failed"] = failed
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    machine_info = result["machine"]
    print(f"soak: {result['bench_command']}")
    load = ", ".join(f"{value:.2f}" for value in machine_info["load_average"])
    print(
        f"on {machine_info['cpu']}, {machine_info['cores']} cores, Python "
        f"{machine_info['python']}, load average at start {load}"
    )
    print(markdown(result, failed))
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main())
