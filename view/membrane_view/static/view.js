// The page: a WebSocket from the bridge (membrane_view.bridge), frames drawn on a canvas,
// a probe driven by the pointer. State for tests and benchmarks is on window.membraneView.
import { ForcePlot, HeatMap, Rope, Scatter } from "./render2d.js";
import { Surface3D } from "./render3d.js";
import { decodeFrame } from "./wire.js";

const $ = (id) => document.getElementById(id);
const surface = $("surface");
const forcePlot = new ForcePlot($("force-plot"));
const state = {
  scene: null, renderer: null, frame: null, fresh: false, pressed: null,
  framesReceived: 0, framesDrawn: 0, draws: 0, renderFps: 0, frameFps: 0,
  force: 0, errors: [], refused: [], stats: null, connected: false, rendererName: "",
  connects: 0,
};
// Canvas 2D by default (works without a GPU); ?renderer=webgl asks for the shaded 3-D surface.
const query = new URLSearchParams(window.location.search);
const wantWebGL = query.get("renderer") === "webgl";
// The bridge's token (printed by `membrane view`), passed on to the WebSocket.
const token = query.get("token") || "";
window.membraneView = state;

function showError(message) {
  state.errors.push(message);
  $("error").textContent = message;
  $("error").hidden = false;
  $("status").textContent = "error";
}

function showStatus(message) {
  $("error").hidden = true;
  $("status").textContent = message;
}

// The bridge refused one of this page's messages: shown for a few seconds, nothing else
// changes (the connection and the session are kept; no reconnect).
let refusedTimer = null;
function showRefused(message) {
  state.refused.push(message);
  $("error").textContent = message;
  $("error").hidden = false;
  clearTimeout(refusedTimer);
  refusedTimer = setTimeout(() => {
    if ($("error").textContent === message) $("error").hidden = true;
  }, 5000);
}

// A grid's heat map or rope; a point list where its points are (a scatter on a membrane).
function canvasRenderer(scene) {
  if (scene.shape.length === 2) return new HeatMap(surface, scene.shape);
  const points = scene.points;
  if (points && points.length && points[0].length === 2) {
    surface.height = surface.width;
    return new Scatter(surface, points, scene.lo, scene.hi);
  }
  const span = Math.max(scene.hi[0] - scene.lo[0], 1e-12);
  const xs = points ? points.map(([x]) => (x - scene.lo[0]) / span) : null;
  return new Rope(surface, scene.shape, xs);
}

function onScene(scene) {
  state.scene = scene;
  $("title").textContent = `membrane view: ${scene.name}`;
  const twoD = scene.shape.length === 2;
  if (!twoD) { surface.height = 320; }
  state.renderer = null;
  if (twoD && wantWebGL) {
    try {
      state.renderer = new Surface3D(surface, scene.shape);
      state.rendererName = "webgl";
    } catch (error) {
      console.warn(`WebGL unavailable, drawing with Canvas 2D: ${error.message}`);
    }
  }
  if (!state.renderer) {
    state.renderer = canvasRenderer(scene);
    state.rendererName = "canvas2d";
  }
  $("probe-panel").hidden = !scene.live;
  $("hint").textContent = scene.live
    ? `live: press and drag on the ${twoD ? "surface" : "rope"} to push a probe`
    : "film scene: playing at its dt";
  updateDepth();
}

function depth() {
  return state.scene ? Number($("depth").value) * state.scene.depth_max : 0;
}

function updateDepth() {
  $("depth-value").textContent = depth().toPrecision(3);
}

// Pointer position -> lattice coordinates (problem units) and canvas pixels.
function probeAt(event) {
  const rect = surface.getBoundingClientRect();
  const u = (event.clientX - rect.left) / rect.width, v = (event.clientY - rect.top) / rect.height;
  const { lo, hi, shape, radius } = state.scene;
  const [a, b] = state.renderer?.pick ? state.renderer.pick(u, v) : [u, 1 - v];
  const at = [lo[0] + a * (hi[0] - lo[0])];
  if (shape.length === 2) at.push(lo[1] + b * (hi[1] - lo[1]));
  const px = u * surface.width, py = v * surface.height;
  const pr = (radius / Math.max(hi[0] - lo[0], 1e-12)) * surface.width;
  return { at, px, py, pr };
}

let socket = null;

function send(message) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
}
state.send = send; // for tests: what the page would send

function press(event) {
  if (!state.scene || !state.scene.live) return;
  state.pressed = probeAt(event);
  send({ type: "press", at: state.pressed.at, depth: depth(), radius: state.scene.radius });
}

surface.addEventListener("pointerdown", (event) => {
  surface.setPointerCapture?.(event.pointerId);
  press(event);
});
surface.addEventListener("pointermove", (event) => { if (state.pressed) press(event); });
for (const kind of ["pointerup", "pointercancel"]) {
  surface.addEventListener(kind, () => { state.pressed = null; send({ type: "release" }); });
}
$("depth").addEventListener("input", () => {
  updateDepth();
  if (state.pressed) {
    send({ type: "press", at: state.pressed.at, depth: depth(), radius: state.scene.radius });
  }
});
$("reset").addEventListener("click", () => send({ type: "reset" }));

function onStats(message) {
  state.stats = message;
  const s = message.server || {}, b = message.bridge || {}, lat = s.latency_us || {};
  const us = (v) => (v == null ? "-" : `${Number(v).toFixed(0)} us`);
  $("stats").textContent = [
    `renderer: ${state.rendererName}`,
    `server: ${s.requests ?? "-"} requests, p50 ${us(lat.p50)}, p99 ${us(lat.p99)}`,
    `live steps served: ${s.live_steps ?? 0}`,
    `bridge: ${b.frames} frames, ${b.steps} steps, ${b.dropped_steps} dropped`,
    `bridge time per frame: p50 ${us(b.bridge_us?.p50)}, p99 ${us(b.bridge_us?.p99)}`,
  ].join("\n");
}

// Reconnect after the bridge went away, waiting longer each time (1 s, 2 s, ... 30 s) so that a
// bridge that keeps refusing is not asked again every second; a scene resets the wait.
const RETRY_MIN_MS = 1000, RETRY_MAX_MS = 30000;
let retryMs = RETRY_MIN_MS;

function connect() {
  const url = new URL("ws", window.location.href);
  url.protocol = url.protocol === "https:" ? "wss:" : "ws:";
  url.search = new URLSearchParams({ token }).toString();
  state.connects += 1;
  socket = new WebSocket(url);
  socket.binaryType = "arraybuffer";
  socket.onopen = () => { state.connected = true; showStatus("bridge connected, asking the server..."); };
  socket.onmessage = (event) => {
    if (typeof event.data === "string") {
      const message = JSON.parse(event.data);
      if (message.type === "scene") { retryMs = RETRY_MIN_MS; onScene(message); }
      else if (message.type === "stats") onStats(message);
      else if (message.type === "error" && message.source === "page") showRefused(message.message);
      else if (message.type === "error") showError(message.message);
      else if (message.type === "status") showStatus(message.message);
      return;
    }
    const frame = decodeFrame(event.data);
    state.frame = frame;
    state.fresh = true;
    state.framesReceived += 1;
    if (frame.live) {
      state.force = frame.force;
      forcePlot.push(frame.force);
    }
  };
  socket.onclose = () => {
    state.connected = false;
    const wait = retryMs;
    retryMs = Math.min(RETRY_MAX_MS, retryMs * 2);
    showError(
      "the bridge closed the connection or refused it (is `membrane view` still running? " +
      "open the address it printed, with its ?token=); retrying in " + `${wait / 1000} s`
    );
    setTimeout(connect, wait);
  };
}

// Draw every animation frame (the page's own counter measures the drawing rate).
let lastCount = performance.now(), drawsThen = 0, framesThen = 0;
function tick(now) {
  if (state.renderer && state.frame) {
    state.renderer.draw(state.frame.z, state.pressed);
    state.draws += 1;
    if (state.fresh) { state.framesDrawn += 1; state.fresh = false; }
    $("force").textContent = state.frame.live ? state.force.toPrecision(4) : "-";
    $("time").textContent = state.frame.t.toFixed(3);
    $("step").textContent = state.frame.k;
    forcePlot.draw();
  }
  if (now - lastCount >= 1000) {
    const seconds = (now - lastCount) / 1000;
    state.renderFps = (state.draws - drawsThen) / seconds;
    state.frameFps = (state.framesReceived - framesThen) / seconds;
    drawsThen = state.draws; framesThen = state.framesReceived; lastCount = now;
    $("render-fps").textContent = state.renderFps.toFixed(0);
    $("frame-fps").textContent = state.frameFps.toFixed(0);
  }
  requestAnimationFrame(tick);
}

connect();
requestAnimationFrame(tick);
