"""The page in a real browser: Debian's headless Chromium driven by Playwright (no browser
download: the executable is /usr/bin/chromium, or $MEMBRANE_CHROMIUM). Skips, with one line,
only when no Chromium or no Playwright is installed (`.ci/run` installs Chromium)."""

from __future__ import annotations

import math
import os
import shutil
import time
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
    """A page with the bridge's Content-Security-Policy in force: a violation (something the
    page would fetch or evaluate from elsewhere) fails the test, as an uncaught error does."""
    context = browser.new_context(viewport={"width": 1100, "height": 760})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on(
        "console",
        lambda message: (
            errors.append(message.text) if "Content Security Policy" in message.text else None
        ),
    )
    yield page
    context.close()
    assert not errors, errors


def wait_for(page: Any, expression: str, timeout_s: float = 15.0) -> Any:
    """Poll a JavaScript expression until it is truthy (Playwright's wait_for_function
    evaluates a string with eval, which the bridge's policy forbids)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = page.evaluate(expression)
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not true within {timeout_s} s: {expression}")
        page.wait_for_timeout(50)


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
    wait_for(page, "window.membraneView.framesDrawn > 5")
    first = _canvas_pixels(page)
    wait_for(page, "window.membraneView.framesDrawn > 20")
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
    wait_for(page, "window.membraneView.framesDrawn > 3")
    assert float(page.evaluate("window.membraneView.force")) == 0.0
    page.locator("#depth").fill("0.5")  # half of the slider: 0.01 on the unit patch
    box = page.locator("#surface").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    wait_for(page, "window.membraneView.force > 0")
    wait_for(page, "Number(document.getElementById('force').textContent) > 0")
    dent = page.evaluate(
        "(() => { const z = window.membraneView.frame.z; return z[10 * 20 + 10]; })()"
    )
    assert dent < -0.005  # the surface is pushed in under the tip
    page.mouse.up()
    wait_for(page, "window.membraneView.force === 0")


def test_an_unreachable_server_is_shown_on_the_page(page: Any, start_bridge: BridgeFactory) -> None:
    bridge = start_bridge("tcp://127.0.0.1:9", timeout=0.2)
    page.goto(bridge.url)
    page.wait_for_selector("#error:not([hidden])", timeout=15000)
    assert "server unreachable" in page.locator("#error").inner_text()


def test_the_webgl_surface_draws_and_a_press_on_it_gives_a_force(
    page: Any, live_server: Server, start_bridge: BridgeFactory, tmp_path: Any
) -> None:
    bridge = start_bridge(live_server.address, scene="membrane-live")
    page.goto(bridge.url + "&renderer=webgl")
    wait_for(page, "window.membraneView.framesDrawn > 3")
    renderer = page.evaluate("window.membraneView.rendererName")
    if renderer != "webgl":
        pytest.skip("this Chromium has no WebGL: the page fell back to Canvas 2D")
    box = page.locator("#surface").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] * 0.55)
    page.mouse.down()
    wait_for(page, "window.membraneView.force > 0")
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
    wait_for(page, "window.membraneView.framesDrawn > 5")
    first = _canvas_pixels(page)
    wait_for(page, "window.membraneView.framesDrawn > 20")
    assert len(set(first)) > 10, "the canvas is blank"
    assert first != _canvas_pixels(page), "the canvas did not change between two frames"
    assert page.evaluate("window.membraneView.frame.z.length") == 64
    assert page.locator("#error").is_hidden()


HOSTILE_PAGE = """<!doctype html><title>elsewhere</title><script>
// A page from another origin tries the bridge's WebSocket, with and without the right token.
function attempt(url) {
  return new Promise((resolve) => {
    let ws;
    try { ws = new WebSocket(url); } catch (error) { resolve("threw " + error.name); return; }
    const timer = setTimeout(() => resolve("timeout"), 8000);
    ws.onopen = () => { clearTimeout(timer); ws.close(); resolve("open"); };
    ws.onmessage = () => { clearTimeout(timer); resolve("read a message"); };
    ws.onclose = (event) => { clearTimeout(timer); resolve("closed " + event.code); };
  });
}
(async () => {
  const results = {};
  results.token = await attempt("WS_URL");
  results.none = await attempt("WS_BASE");
  window.results = results;
  document.title = "done";
})();
</script>"""


class PageServer:
    """Another origin on loopback: one HTML page at /, from a thread (stdlib http.server)."""

    def __init__(self, html: str):
        import http.server
        import threading

        body = html.encode()

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", "text/html; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = int(self.server.server_address[1])
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=10)


def _hostile(bridge: Any) -> str:
    return HOSTILE_PAGE.replace("WS_URL", bridge.ws_url).replace(
        "WS_BASE", bridge.ws_url.split("?")[0]
    )


def test_a_page_from_another_origin_cannot_open_the_websocket(
    page: Any, start_server: Any, start_bridge: BridgeFactory
) -> None:
    """Even with the right token (which a foreign page would not know): the Origin is not the
    bridge's, so the handshake is refused and no session is opened."""
    from membrane_view.bridge import PAGES

    server = start_server(["membrane-live"])
    bridge = start_bridge(server.address, scene="membrane-live")
    elsewhere = PageServer(_hostile(bridge))
    try:
        page.goto(f"http://127.0.0.1:{elsewhere.port}/")
        results = wait_for(page, "window.results")
    finally:
        elsewhere.stop()
    assert results == {"token": "closed 1006", "none": "closed 1006"}, results
    assert len(server.sessions) == 0 and bridge.runner.app[PAGES].open == 0
    # The same bridge serves its own page, opened from its own address.
    page.goto(bridge.url)
    wait_for(page, "window.membraneView.framesDrawn > 3")
    assert len(server.sessions) == 1


def test_dns_rebinding_gets_403_in_a_real_browser(
    browser: Any, start_server: Any, start_bridge: BridgeFactory
) -> None:
    """evil.example resolved to 127.0.0.1 (Chromium's --host-resolver-rules): the page under
    that name gets 403 and a page from that name cannot open the WebSocket."""
    server = start_server(["membrane-live"])
    bridge = start_bridge(server.address, scene="membrane-live")
    elsewhere = PageServer(_hostile(bridge).replace("127.0.0.1", "evil.example"))
    rules = "--host-resolver-rules=MAP evil.example 127.0.0.1"
    try:
        chromium = browser.browser_type.launch(
            executable_path=CHROMIUM, headless=True, args=["--no-sandbox", rules]
        )
        try:
            rebound = chromium.new_page()
            reply = rebound.goto(f"http://evil.example:{bridge.port}/?token={bridge.token}")
            assert reply is not None and reply.status == 403
            assert "Host is not this bridge's address" in rebound.content()
            rebound.goto(f"http://evil.example:{elsewhere.port}/")
            results = wait_for(rebound, "window.results")
        finally:
            chromium.close()
    finally:
        elsewhere.stop()
    assert results == {"token": "closed 1006", "none": "closed 1006"}, results
    assert len(server.sessions) == 0


def test_a_refused_message_is_shown_and_the_page_stays_connected(
    page: Any, start_server: Any, start_bridge: BridgeFactory
) -> None:
    """A bad message from the page (as a hostile script in it would send) is shown in the error
    bar; the page neither reconnects nor loses its session, and a press still works."""
    server = start_server(["membrane-live"])
    bridge = start_bridge(server.address, scene="membrane-live")
    page.goto(bridge.url)
    wait_for(page, "window.membraneView.framesDrawn > 3")
    page.evaluate(
        """() => {
        const send = window.membraneView.send;
        send({ type: "press", at: [0.5], depth: 0.01, radius: 0.05 });
        send({ type: "press", at: [0.5, 0.5], depth: 1.0, radius: 0.05 });
        send({ type: "press", at: [0.5, 0.5], depth: true, radius: 1e-4 });
        send({ type: "what" });
    }"""
    )
    wait_for(page, "window.membraneView.refused.length >= 4")
    assert "page message refused" in page.locator("#error").inner_text()
    frames = page.evaluate("window.membraneView.framesReceived")
    page.wait_for_timeout(2500)  # the old page reconnected after 1 s
    state = page.evaluate(
        "(({connects, framesReceived, connected, force}) =>"
        " ({connects, framesReceived, connected, force}))(window.membraneView)"
    )
    assert state["connects"] == 1 and state["connected"] and state["force"] == 0, state
    assert state["framesReceived"] > frames + 20, state
    assert len(server.sessions) == 1
    box = page.locator("#surface").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    wait_for(page, "window.membraneView.force > 0")
    page.mouse.up()
    wait_for(page, "window.membraneView.force === 0")
    page.locator("#reset").click()
    wait_for(page, "window.membraneView.frame.k < 500")
    assert page.evaluate("window.membraneView.connects") == 1
