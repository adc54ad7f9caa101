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
    """A coarse sample of the surface's pixels as the page shows them (RGB, 16 x 16 grid, from
    a screenshot: the WebGL canvas has no 2-D context to read)."""
    image = _surface_image(page)
    width, height = image.size
    out: list[int] = []
    for a in range(16):
        for b in range(16):
            out.extend(image.getpixel((int((a + 0.5) * width / 16), int((b + 0.5) * height / 16))))
    return out


def _surface_image(page: Any) -> Any:
    """The surface and its overlay as shown, in canvas pixels (RGB)."""
    import io

    from PIL import Image

    png = page.locator("#stage").screenshot()
    width = page.evaluate("document.getElementById('surface').width")
    height = page.evaluate("document.getElementById('surface').height")
    with Image.open(io.BytesIO(png)) as shot:
        return shot.convert("RGB").resize((width, height))


def _press_at(page: Any, x: float, y: float) -> None:
    """Press the pointer on the page where scene point (x, y) is drawn."""
    cx, cy = page.evaluate(f"window.membraneView.clientPoint({x}, {y})")
    page.mouse.move(cx, cy)
    page.mouse.down()


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
    """With the Canvas 2D heat map (the fallback, asked for): a press, its force, release."""
    bridge = start_bridge(live_server.address, scene="membrane-live")
    page.goto(bridge.url + "&renderer=canvas")
    wait_for(page, "window.membraneView.framesDrawn > 3")
    assert page.evaluate("window.membraneView.rendererName") == "canvas2d"
    assert float(page.evaluate("window.membraneView.force")) == 0.0
    page.locator("#depth").fill("0.5")  # half of the slider: 0.01 on the unit patch
    _press_at(page, 0.5, 0.5)
    wait_for(page, "window.membraneView.force > 0")
    wait_for(page, "parseFloat(document.getElementById('force').textContent) > 0")
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
    page.goto(bridge.url)  # WebGL is the default
    wait_for(page, "window.membraneView.framesDrawn > 3")
    assert page.evaluate("window.membraneView.rendererName") == "webgl", "fell back to Canvas 2D"
    _press_at(page, 0.5, 0.5)
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
    _press_at(page, 0.5, 0.5)
    wait_for(page, "window.membraneView.force > 0")
    page.mouse.up()
    wait_for(page, "window.membraneView.force === 0")
    page.locator("#reset").click()
    wait_for(page, "window.membraneView.frame.k < 500")
    assert page.evaluate("window.membraneView.connects") == 1


# The labels as the page shows them, and the range of the frame they were drawn from, read in one
# evaluation (the page draws between two evaluations, never during one).
LABELS = """(() => {
  const v = window.membraneView, text = (id) => document.getElementById(id).textContent;
  let lo = Infinity, hi = -Infinity;
  for (const value of v.drawn.z) { lo = Math.min(lo, value); hi = Math.max(hi, value); }
  return {
    renderer: v.rendererName, range: { lo, hi }, factor: v.units.factor,
    tickMin: text('tick-min'), tickMax: text('tick-max'), colourUnit: text('colour-unit'),
    force: text('force'), depth: text('depth-value'), scaleBar: v.scaleBarLabel,
  };
})()"""


def _ticks_match_the_frame(labels: dict[str, Any]) -> None:
    """The colour bar's ticks are the drawn frame's min and max (display units), 2 digits."""
    for tick, value in (("tickMin", "lo"), ("tickMax", "hi")):
        shown = float(labels[tick])
        expected = float(f"{labels['range'][value] * labels['factor']:.2g}")
        assert shown == pytest.approx(expected, rel=1e-12, abs=0.0), (tick, labels)


def test_the_default_page_is_a_webgl_surface_with_its_colour_bar_and_units(
    page: Any, live_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(live_server.address, scene="membrane-live")
    page.goto(bridge.url)
    wait_for(page, "window.membraneView.framesDrawn > 3")
    _press_at(page, 0.5, 0.5)  # the soft tip: a dent, so that min and max differ
    wait_for(page, "window.membraneView.drawn?.range.lo < -0.001")
    labels = page.evaluate(LABELS)
    assert labels["renderer"] == "webgl", "the default page fell back to Canvas 2D"
    _ticks_match_the_frame(labels)
    assert labels["colourUnit"] == "(problem units)"
    assert labels["force"].endswith(" problem units") and labels["scaleBar"] == "0.2 problem units"
    assert len(set(_canvas_pixels(page))) > 30, "the WebGL surface is blank"


def test_on_the_skin_patch_the_labels_are_in_mm_and_n(
    page: Any, skin_server: Server, start_bridge: BridgeFactory
) -> None:
    bridge = start_bridge(skin_server.address, scene="skin-patch", timeout=10.0)
    page.goto(bridge.url)
    wait_for(page, "window.membraneView.framesDrawn > 3")
    page.select_option("#tool", "sphere")
    page.locator("#depth").fill("0.4")  # 2 mm of the slider's 5
    _press_at(page, 0.025, 0.025)
    wait_for(page, "window.membraneView.force > 0.1")
    labels = page.evaluate(LABELS)
    assert labels["renderer"] == "webgl"
    _ticks_match_the_frame(labels)
    # The dent, in mm: the 5 mm sphere 2 mm deep; the lattice points nearest its centre are
    # 1.84 mm off it, where its surface is 1.65 mm deep.
    assert -2.0 <= labels["range"]["lo"] * 1e3 <= -1.6
    assert labels["colourUnit"] == "(mm)" and labels["depth"] == "2 mm"
    assert labels["force"].endswith(" N") and float(labels["force"].split()[0]) > 0.1
    assert labels["scaleBar"] == "10 mm"
    page.mouse.up()


def test_a_press_darkens_the_surface_under_the_tool_by_a_tenth_of_the_colour_range(
    page: Any, skin_server: Server, start_bridge: BridgeFactory
) -> None:
    """On the 20 x 20 skin patch: the mean pixel value under the tool, pressed against the page
    at rest, moves by at least 10 % of the colour ramp's range (its two ends' mean RGB)."""
    bridge = start_bridge(skin_server.address, scene="skin-patch", timeout=10.0)
    page.goto(bridge.url)
    wait_for(page, "window.membraneView.framesDrawn > 3")
    assert page.evaluate("window.membraneView.scene.shape") == [20, 20]
    at_rest = _surface_image(page)
    page.select_option("#tool", "sphere")
    page.locator("#depth").fill("0.6")  # 3 mm
    _press_at(page, 0.025, 0.025)
    wait_for(page, "window.membraneView.force > 0.1 && window.membraneView.toolScreen")
    page.wait_for_timeout(300)
    spot = page.evaluate("window.membraneView.toolScreen")
    pressed = _surface_image(page)
    low, high = page.evaluate("window.membraneView.rampEnds")
    colour_range = abs(sum(high) - sum(low)) / 3
    radius = max(4.0, 0.5 * spot["r"])
    change = _disc_mean(pressed, spot, radius) - _disc_mean(at_rest, spot, radius)
    assert abs(change) >= 0.1 * colour_range, (change, colour_range, spot)
    page.mouse.up()


def _disc_mean(image: Any, spot: dict[str, float], radius: float) -> float:
    """The mean of R, G and B over the pixels within ``radius`` of the spot."""
    values = []
    for x in range(int(spot["x"] - radius), int(spot["x"] + radius) + 1):
        for y in range(int(spot["y"] - radius), int(spot["y"] + radius) + 1):
            if (x - spot["x"]) ** 2 + (y - spot["y"]) ** 2 <= radius**2:
                values.append(sum(image.getpixel((x, y))) / 3)
    assert values, spot
    return sum(values) / len(values)
