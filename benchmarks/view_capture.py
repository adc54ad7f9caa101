"""The README's screenshot and GIF, taken from the page itself in headless Chromium (not a test):
`skin-patch` pressed by a 5 mm sphere, its depth ramped up and held, then released.

    .venv/bin/python benchmarks/view_capture.py [--png docs/view.png] [--gif docs/view.gif]

A server and a bridge run in this process on loopback (the tests' bridge thread); the FEM tables
come from the user's cache (built once, about 12 s, when missing). Each GIF frame is a screenshot
of the page, shown for the wall-clock time it stood for.
"""

from __future__ import annotations

import argparse
import io
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "tests" / "view"))  # the tests' bridge thread

from PIL import Image
from playwright.sync_api import FloatRect, Page, sync_playwright
from view_fixtures import BridgeThread

from membrane_server.server import Server
from membrane_view.bridge import BridgeConfig

CHROMIUM = "/usr/bin/chromium"
CLIP: FloatRect = {"x": 0, "y": 0, "width": 1100, "height": 690}


def _shot(page: Page) -> Image.Image:
    with Image.open(io.BytesIO(page.screenshot(clip=CLIP))) as image:
        return image.convert("RGB")


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--png", type=Path, default=Path("docs/view.png"))
    parser.add_argument("--gif", type=Path, default=Path("docs/view.gif"))
    parser.add_argument("--width", type=int, default=720, help="the GIF's width in pixels")
    args = parser.parse_args()
    server = Server(["skin-patch"], bind="tcp://127.0.0.1:*")
    server.start()
    bridge = BridgeThread(BridgeConfig(connect=server.address, scene="skin-patch", timeout=10.0))
    frames: list[tuple[Image.Image, float]] = []
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1100, "height": 760}, bypass_csp=True)
            page.goto(bridge.url)
            page.wait_for_function("window.membraneView.framesDrawn > 5", timeout=60000)
            page.select_option("#tool", "sphere")
            page.locator("#depth").fill("0.1")
            x, y = page.evaluate("window.membraneView.clientPoint(0.022, 0.027)")
            page.mouse.move(x, y)

            def record(seconds: float) -> None:
                end = time.perf_counter() + seconds
                while time.perf_counter() < end:
                    frames.append((_shot(page), time.perf_counter()))

            record(0.6)
            page.mouse.down()
            for depth in (0.2, 0.35, 0.5, 0.6):
                page.locator("#depth").fill(str(depth))
                record(0.5)
            record(0.6)
            _shot(page).save(args.png, optimize=True)
            page.mouse.up()
            record(1.2)
            browser.close()
    finally:
        bridge.stop()
        server.stop()
    _write_gif(frames, args.gif, args.width)
    print(f"{args.png}: {args.png.stat().st_size} bytes; {args.gif}: {len(frames)} frames, "
          f"{args.gif.stat().st_size} bytes")  # fmt: skip
    return 0


def _write_gif(frames: list[tuple[Image.Image, float]], path: Path, width: int) -> None:
    """Each screenshot shown until the next one was taken (the last for a second)."""
    height = round(width * CLIP["height"] / CLIP["width"])
    images = [image.resize((width, height), Image.Resampling.LANCZOS) for image, _ in frames]
    times = [t for _, t in frames]
    durations = [max(20, round(1000 * (b - a))) for a, b in itertools.pairwise(times)] + [1000]
    palette = [image.quantize(colors=128, method=Image.Quantize.MEDIANCUT) for image in images]
    palette[0].save(
        path, save_all=True, append_images=palette[1:], duration=durations, loop=0, optimize=True
    )


if __name__ == "__main__":
    sys.exit(main())
