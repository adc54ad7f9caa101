"""Figures for docs/VIEW.md (not a test): several live pages on one server at once, as a user
runs them: `membrane serve` and `membrane view` as processes of their own, the pages in one
headless Chromium, each pressed at its centre. Per page: steps taken and dropped by the bridge
over the window, draws and frames per second; per process: CPU seconds over the window (what
saturates the machine's cores).

    .venv/bin/python benchmarks/view_pages.py [--pages 3] [--seconds 10] [--scene membrane-live]
        [--renderer webgl|canvas] [--no-press] [--profile server|bridge]

``--profile`` runs the server (or the bridge) under cProfile and prints its top functions by
own time; ``--no-press`` leaves the pages unpressed (free steps).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

CHROMIUM = "/usr/bin/chromium"
MEMBRANE = str(Path(sys.executable).with_name("membrane"))
TICKS = os.sysconf("SC_CLK_TCK")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cpu_seconds(pids: list[int]) -> float:
    """User + system CPU of processes (and their threads), from /proc."""
    total = 0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except FileNotFoundError:
            continue
        total += int(fields[11]) + int(fields[12])
    return total / TICKS


def _children(pid: int) -> list[int]:
    """A process and all its descendants."""
    out, todo = [], [pid]
    while todo:
        current = todo.pop()
        out.append(current)
        for task in Path(f"/proc/{current}/task").iterdir():
            children = (task / "children").read_text().split()
            todo.extend(int(c) for c in children)
    return out


def _profiled(command: list[str], profile: Path | None) -> list[str]:
    return (
        command
        if profile is None
        else [sys.executable, "-m", "cProfile", "-o", str(profile), *command]
    )


def _start_view(address: str, scene: str, profile: Path | None) -> tuple[subprocess.Popen, str]:
    command = _profiled(
        [MEMBRANE, "view", "--connect", address, "--scene", scene, "--port", "0"], profile
    )
    view = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert view.stdout is not None
    for line in view.stdout:
        found = re.search(r"(http://\S+\?token=\S+)", line)
        if found:
            return view, found.group(1)
    raise RuntimeError("membrane view printed no address")


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--pages", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--scene", default="membrane-live")
    parser.add_argument("--renderer", choices=["webgl", "canvas"], default="webgl")
    parser.add_argument("--no-press", action="store_true")
    parser.add_argument("--profile", choices=["server", "bridge"])
    args = parser.parse_args()
    profile = Path(f"/tmp/view_pages.{args.profile}.prof") if args.profile else None
    address = f"tcp://127.0.0.1:{_free_port()}"
    serve = subprocess.Popen(
        _profiled([MEMBRANE, "serve", "--scene", args.scene, "--bind", address],
                  profile if args.profile == "server" else None),
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    view, url = _start_view(address, args.scene, profile if args.profile == "bridge" else None)
    results: dict[str, object] = {}
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            pages = []
            for _ in range(args.pages):
                page = browser.new_page(viewport={"width": 1100, "height": 760}, bypass_csp=True)
                page.goto(url + ("&renderer=canvas" if args.renderer == "canvas" else ""))
                page.wait_for_function("window.membraneView.framesDrawn > 5", timeout=60000)
                page.locator("#depth").fill("0.5")
                x, y = page.evaluate(
                    "(() => { const s = window.membraneView.scene;"
                    " return window.membraneView.clientPoint((s.lo[0] + s.hi[0]) / 2,"
                    " (s.lo[1] + s.hi[1]) / 2); })()"
                )
                page.mouse.move(x, y)
                if not args.no_press:
                    page.mouse.down()
                pages.append(page)
            pages[0].wait_for_timeout(2500)  # pressed, and a stats message or two since
            read = (
                "[window.membraneView.draws, window.membraneView.framesReceived,"
                " window.membraneView.stats.bridge]"
            )
            before = [p.evaluate(read) for p in pages]
            processes = {
                "server": _children(serve.pid),
                "bridge": _children(view.pid),
                "chromium": _chromium_pids(),
            }
            cpu0 = {name: _cpu_seconds(pids) for name, pids in processes.items()}
            start = time.perf_counter()
            pages[0].wait_for_timeout(args.seconds * 1000)
            after = [p.evaluate(read) for p in pages]
            elapsed = time.perf_counter() - start
            cpu = {n: round(_cpu_seconds(pids) - cpu0[n], 2) for n, pids in processes.items()}
            results = {
                "scene": args.scene, "renderer": args.renderer, "pages": args.pages,
                "pressed": not args.no_press,
                "seconds": round(elapsed, 2), "cpu_seconds": cpu, "cores": os.cpu_count(),
                "per_page": [_page(b, a, elapsed) for b, a in zip(before, after, strict=True)],
            }  # fmt: skip
            browser.close()
    finally:
        view.terminate()
        serve.terminate()
        view.wait(timeout=30)
        serve.wait(timeout=30)
    print(json.dumps(results, indent=2))
    if profile is not None:
        import pstats

        pstats.Stats(str(profile)).sort_stats("tottime").print_stats(20)
    return 0


def _chromium_pids() -> list[int]:
    """Every Chromium process (the browser, its GPU and renderer processes)."""
    out = subprocess.run(["pgrep", "-f", "chromium"], capture_output=True, text=True)
    return [int(pid) for pid in out.stdout.split()]


def _page(before: list, after: list, elapsed: float) -> dict[str, float]:
    draws0, frames0, bridge0 = before
    draws1, frames1, bridge1 = after
    return {
        "steps_per_s": round((bridge1["steps"] - bridge0["steps"]) / elapsed, 1),
        "dropped_steps": bridge1["dropped_steps"] - bridge0["dropped_steps"],
        "draws_per_s": round((draws1 - draws0) / elapsed, 1),
        "frames_per_s": round((frames1 - frames0) / elapsed, 1),
        "bridge_us": bridge1["bridge_us"],
    }


if __name__ == "__main__":
    sys.exit(main())
