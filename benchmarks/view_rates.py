"""Figures for docs/VIEW.md (not a test): the page's own draw rate in headless Chromium for the
20 x 20 membrane and a 100 x 100 lattice, one page at a time, and the bridge's time per frame.

    .venv/bin/python benchmarks/view_rates.py [--renderer webgl|canvas] [--seconds 5]

Servers and bridges run in this process on loopback, as in the tests. Several pages at once on
one server: benchmarks/view_pages.py; the README's screenshot and GIF: view_capture.py.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "tests" / "view"))  # the tests' bridge thread
sys.path.insert(0, str(Path(__file__).parents[1] / "tests" / "helpers"))

from playwright.sync_api import sync_playwright
from view_fixtures import BridgeThread

from membrane_server.scene import scene_from_dict
from membrane_server.served import ServedScene
from membrane_server.server import Server
from membrane_view.bridge import BridgeConfig

CHROMIUM = "/usr/bin/chromium"


def _scene(n: int) -> ServedScene:
    data = {
        "name": f"membrane-{n}",
        "model": "membrane-forced",
        "evaluator": "exact",
        "lattice": {"nx": n, "ny": n},
        "dt": 0.01,
        "duration": 1.0,
        "policy": "hold",
    }
    return ServedScene.load(scene_from_dict(data))


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--renderer", choices=["canvas", "webgl"], default="webgl")
    parser.add_argument("--scenes", default="membrane-20,membrane-100,membrane-live")
    args = parser.parse_args()
    wanted = args.scenes.split(",")
    scenes = [_scene(int(name.split("-")[1])) if name[-1].isdigit() else name for name in wanted]
    server = Server(scenes, bind="tcp://127.0.0.1:*")
    server.start()
    results = {}
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            for scene in wanted:
                bridge = BridgeThread(BridgeConfig(connect=server.address, scene=scene))
                # bypass_csp: the page's policy forbids the eval wait_for_function relies on
                page = browser.new_page(viewport={"width": 1100, "height": 760}, bypass_csp=True)
                page.goto(bridge.url + ("&renderer=canvas" if args.renderer == "canvas" else ""))
                page.wait_for_function("window.membraneView.framesDrawn > 10", timeout=30000)
                if scene == "membrane-live":
                    page.locator("#depth").fill("0.5")
                    x, y = page.evaluate("window.membraneView.clientPoint(0.4, 0.6)")
                    page.mouse.move(x, y)
                    page.mouse.down()
                draws0, frames0, stats0 = page.evaluate(
                    "[window.membraneView.draws, window.membraneView.framesReceived,"
                    " window.membraneView.stats]"
                )
                start = time.perf_counter()
                page.wait_for_timeout(args.seconds * 1000)  # keeps Playwright reading
                draws1, frames1, stats = page.evaluate(
                    "[window.membraneView.draws, window.membraneView.framesReceived,"
                    " window.membraneView.stats]"
                )
                elapsed = time.perf_counter() - start
                results[scene] = {
                    "draws_per_s": (draws1 - draws0) / elapsed,
                    "frames_per_s": (frames1 - frames0) / elapsed,
                    "bridge_steps_per_s": (stats["bridge"]["steps"] - stats0["bridge"]["steps"])
                    / elapsed,
                    "bridge_dropped_steps": stats["bridge"]["dropped_steps"],
                    "bridge_us": stats["bridge"]["bridge_us"],
                    "server_latency_us": stats["server"]["latency_us"],
                    "renderer": page.evaluate("window.membraneView.rendererName"),
                }
                page.close()
                bridge.stop()
            browser.close()
    finally:
        server.stop()
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
