"""Served step latency of the ``rope-koopman`` scene at 1 kHz against the bare echo's.

`membrane bench --payload step` presses a probe, which the Koopman engine does not take, so this
script sends its own steps: one session opened with a test-split shape, then one step request
every millisecond over a REQ socket (each timed from send to reply), with and without frames;
the echo baseline (`membrane_bench.echo`) gets requests of the same bytes on the same socket
type, with replies of the same length. Server and echo alternate in segments so that a changing
background load weighs on both alike.

    python benchmarks/koopman_step_latency.py --seconds 20 --segments 4 [--spin-us 1500]
"""

from __future__ import annotations

import argparse
import secrets
import socket
import subprocess
import sys
import time

import numpy as np
import zmq

from membrane_bench.echo import EchoServer
from membrane_client import Client
from membrane_client.live_schema import Initial
from membrane_client.protocol import Op, Request
from membrane_models.data.koopman import DatasetSpec, initial_state
from membrane_models.exact.kirchhoff_carrier import sine_basis


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _paced(sock: zmq.Socket, payloads: list[bytes], period: float) -> tuple[np.ndarray, int]:
    """Send each payload at its due time (1 / rate apart), wait for its reply; latencies in us."""
    latencies = np.empty(len(payloads))
    due = time.perf_counter()
    size = 0
    for i, payload in enumerate(payloads):
        due += period
        while time.perf_counter() < due:
            pass
        began = time.perf_counter()
        sock.send(payload)
        size = len(sock.recv())
        latencies[i] = (time.perf_counter() - began) * 1e6
    return latencies, size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="per mode, server and echo")
    parser.add_argument("--segments", type=int, default=4)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument(
        "--spin-us",
        type=float,
        default=0.0,
        help="the server's `membrane serve --spin-us` (0: it blocks between requests)",
    )
    args = parser.parse_args()
    address = f"tcp://127.0.0.1:{_free_port()}"
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "membrane_cli.dispatcher",
            "serve",
            "--scene",
            "rope-koopman",
            "--bind",
            address,
            "--spin-us",
            f"{args.spin_us:g}",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        with Client(address, timeout=30.0) as client:
            client.describe("rope-koopman")
        start = initial_state(DatasetSpec(), "pluck-smooth", "test", 2)
        basis = sine_basis(np.arange(130) / 129, start.q0.size)
        initial = Initial(
            (basis @ start.q0).astype(np.float32), (basis @ start.p0).astype(np.float32)
        )
        context = zmq.Context()
        sock = context.socket(zmq.REQ)
        sock.connect(address)
        token = secrets.token_hex(16)
        opened = Request(
            Op.OPEN, 1, "latency", "rope-koopman", initial=initial.to_wire(), token=token
        )
        sock.send(opened.to_wire())
        sock.recv()
        per_segment = int(args.seconds * args.rate / args.segments)
        results: dict[str, list[np.ndarray]] = {}
        k, ident = 0, 2
        for frame in (False, True):
            label = "step+frame" if frame else "step"
            for _ in range(args.segments):
                payloads = []
                for _ in range(per_segment):
                    request = Request(
                        Op.STEP, ident, "latency", "rope-koopman", k=k, frame=frame, token=token
                    )
                    payloads.append(request.to_wire())
                    k, ident = k + 1, ident + 1
                lat, reply_bytes = _paced(sock, payloads, 1.0 / args.rate)
                results.setdefault(label, []).append(lat)
                with EchoServer(address, reply_bytes) as echo:
                    echo_sock = context.socket(zmq.REQ)
                    echo_sock.connect(echo.address)
                    lat_echo, _ = _paced(echo_sock, payloads, 1.0 / args.rate)
                    echo_sock.close(0)
                results.setdefault(f"echo ({label})", []).append(lat_echo)
        sock.close(0)
        context.term()
    finally:
        server.terminate()
        server.wait(timeout=10)
    print("| what | p50 us | p99 us | p99.9 us |")
    print("| --- | --- | --- | --- |")
    summary = {}
    for label, parts in results.items():
        lat = np.concatenate(parts)
        p50, p99, p999 = np.percentile(lat, [50, 99, 99.9])
        summary[label] = p99
        print(f"| {label} | {p50:.0f} | {p99:.0f} | {p999:.0f} |")
    for label in ("step", "step+frame"):
        print(f"p99 ratio {label} / echo: {summary[label] / summary[f'echo ({label})']:.2f}")


if __name__ == "__main__":
    main()
