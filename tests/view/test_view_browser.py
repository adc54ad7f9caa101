"""The page in a real browser: Debian's headless Chromium driven by Playwright (no browser
download: the executable is /usr/bin/chromium, or $MEMBRANE_CHROMIUM). Skips, with one line,
only when no Chromium or no Playwright is installed (`.ci/run` installs Chromium)."""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Iterator
from typing import Any

import pytest
from view_fixtures import BridgeFactory

from membrane_server.server import Server

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")

# A real browser per test: part of `make test`, not of the fast lane.
pytestmark = pytest.mark.slow

CHROMIUM = os.environ.get("MEMBRANE_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(
            executable_path=CHROMIUM, headless=True, args=["--no-sandbox"]
        )
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": 1100, "height": 760})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    yield page
    context.close()
    assert not errors, errors


def _canvas_pixels(page: Any) -> list[int]:
    """A coarse sample of the surface canvas's pixels (RGB, 16 x 16 grid)."""
    return page.evaluate(
        """() => {
        const c = document.getElementById('surface');
        const ctx = c.getContext('2d');
        const out = [];
        for (let a = 0; a < 16; a++) for (let b = 0; b < 16; b++) {
          const x = (a + 0.5) * c.width / 16, y = (b + 0.5) * c.height / 16;
          const d = ctx.getImageData(x, y, 1, 1).data;
          out.push(d[0], d[1], d[2]);
        }
        return out;
    }"""
    )


def test_a_film_plays_on_the_canvas(
    page: Any, membrane_server: Server, start_bridge: BridgeFactory, tmp_path: Any
) -> None:
    bridge = start_bridge(membrane_server.address, scene="membrane", speed=0.5)
    page.goto(bridge.url)
    page.wait_for_function("window.membraneView.framesDrawn > 5", timeout=15000)
    first = _canvas_pixels(page)
    page.wait_for_function("window.membraneView.framesDrawn > 20", timeout=15000)
    second = _canvas_pixels(page)
    png = page.locator("#surface").screenshot(path=str(tmp_path / "film.png"))
    assert len(png) > 1000
    assert len(set(first)) > 10, "the canvas is blank"
    assert first != second, "the canvas did not change between two frames"
    assert "membrane" in page.locator("#title").inner_text()
    assert page.locator("#error").is_hidden()


def test_a_pointer_press_on_a_live_scene_shows_a_positive_force(
    page: Any, live_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(live_server.address, scene="membrane-live")
    page.goto(bridge.url)
    page.wait_for_function("window.membraneView.framesDrawn > 3", timeout=15000)
    assert float(page.evaluate("window.membraneView.force")) == 0.0
    page.locator("#depth").fill("0.5")  # half of the slider: 0.01 on the unit patch
    box = page.locator("#surface").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_function("window.membraneView.force > 0", timeout=15000)
    page.wait_for_function("Number(document.getElementById('force').textContent) > 0")
    dent = page.evaluate(
        "(() => { const z = window.membraneView.frame.z; return z[10 * 20 + 10]; })()"
    )
    assert dent < -0.005  # the surface is pushed in under the tip
    page.mouse.up()
    page.wait_for_function("window.membraneView.force === 0", timeout=15000)


def test_an_unreachable_server_is_shown_on_the_page(page: Any, start_bridge: BridgeFactory) -> None:
    bridge = start_bridge("tcp://127.0.0.1:9", timeout=0.2)
    page.goto(bridge.url)
    page.wait_for_selector("#error:not([hidden])", timeout=15000)
    assert "server unreachable" in page.locator("#error").inner_text()


def test_the_webgl_surface_draws_and_a_press_on_it_gives_a_force(
    page: Any, live_server: Server, start_bridge: BridgeFactory, tmp_path: Any
) -> None:
    bridge = start_bridge(live_server.address, scene="membrane-live")
    page.goto(bridge.url + "?renderer=webgl")
    page.wait_for_function("window.membraneView.framesDrawn > 3", timeout=15000)
    renderer = page.evaluate("window.membraneView.rendererName")
    if renderer != "webgl":
        pytest.skip("this Chromium has no WebGL: the page fell back to Canvas 2D")
    box = page.locator("#surface").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] * 0.55)
    page.mouse.down()
    page.wait_for_function("window.membraneView.force > 0", timeout=15000)
    from PIL import Image

    path = tmp_path / "webgl.png"
    page.locator("#surface").screenshot(path=str(path))
    with Image.open(path) as image:
        colours = image.convert("RGB").getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 50, "the WebGL canvas is blank"
    page.mouse.up()


def test_a_point_list_is_drawn_where_its_points_are(
    page: Any, start_server: Any, start_bridge: BridgeFactory
) -> None:
    """A membrane's explicit point list (no grid): a scatter of discs coloured by displacement."""
    from membrane_server.scene import scene_from_dict

    ring = [[0.5 + 0.3 * math.cos(a / 10), 0.5 + 0.3 * math.sin(a / 10)] for a in range(63)]
    scene = scene_from_dict(
        {"name": "ring", "model": "membrane-forced", "evaluator": "exact",
         "lattice": {"points": [[0.8, 0.5], *ring]}, "dt": 0.01, "duration": 1.0}
    )  # fmt: skip
    server = start_server([scene])
    bridge = start_bridge(server.address, scene="ring", speed=0.5)
    page.goto(bridge.url)
    page.wait_for_function("window.membraneView.framesDrawn > 5", timeout=15000)
    first = _canvas_pixels(page)
    page.wait_for_function("window.membraneView.framesDrawn > 20", timeout=15000)
    assert len(set(first)) > 10, "the canvas is blank"
    assert first != _canvas_pixels(page), "the canvas did not change between two frames"
    assert page.evaluate("window.membraneView.frame.z.length") == 64
    assert page.locator("#error").is_hidden()
