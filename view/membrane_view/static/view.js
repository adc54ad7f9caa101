// The page: a WebSocket from the bridge (membrane_view.bridge), frames drawn as a shaded 3-D
// surface (WebGL; the Canvas 2D heat map where WebGL is missing, or with ?renderer=canvas),
// a colour bar on the frame's own range, a scale bar, and the tool the pointer presses with,
// drawn where it presses. Labels are in the scene's units (mm and N on a physical scene).
// State for tests and benchmarks is on window.membraneView.
import { formatValue, frameRange, niceLength, ramp, rampBytes } from "./colour.js";
import { ForcePlot, HeatMap, Rope, Scatter } from "./render2d.js";
import { Surface3D } from "./render3d.js";
import { decodeFrame } from "./wire.js";

const $ = (id) => document.getElementById(id);
const stage = $("stage");
const overlay = $("overlay");
const forcePlot = new ForcePlot($("force-plot"));
const TOOL_NAMES = {
  tip: "soft tip (probe)", sphere: "sphere", cylinder: "cylinder (flat punch)",
  grasp: "grasp (hold and lift)",
};
const PROBLEM_UNITS = { length: "problem units", factor: 1, force: "problem units", physical: false };
const state = {
  scene: null, renderer: null, frame: null, fresh: false, pressed: null,
  framesReceived: 0, framesDrawn: 0, draws: 0, renderFps: 0, frameFps: 0,
  force: 0, errors: [], refused: [], stats: null, connected: false, rendererName: "",
  connects: 0, units: PROBLEM_UNITS, drawn: null, toolScreen: null, scaleBar: null,
  scaleBarLabel: "", rampEnds: [ramp(0), ramp(1)],
};
// WebGL by default; ?renderer=canvas (or canvas2d) asks for the Canvas 2D heat map.
const query = new URLSearchParams(window.location.search);
const forceCanvas = ["canvas", "canvas2d"].includes(query.get("renderer"));
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

// A fresh canvas per scene: one that held a WebGL context cannot give a 2-D one.
function freshSurface(height) {
  const old = $("surface"), canvas = document.createElement("canvas");
  canvas.id = "surface";
  canvas.width = old.width;
  canvas.height = height;
  canvas.setAttribute("aria-label", "the lattice");
  old.replaceWith(canvas);
  overlay.width = canvas.width;
  overlay.height = height;
  return canvas;
}

function canvasRenderer(canvas, scene) {
  if (scene.shape.length === 2) return new HeatMap(canvas, scene);
  const points = scene.points;
  if (points && points.length && points[0].length === 2) return new Scatter(canvas, scene);
  return new Rope(canvas, scene, points ? points.map(([x]) => x) : null);
}

function chooseRenderer(scene) {
  const surfaceLike = scene.shape.length === 2 || (scene.triangles && scene.points?.[0]?.length === 2);
  const canvas = freshSurface(scene.shape.length === 1 && !surfaceLike ? 320 : 640);
  if (surfaceLike && !forceCanvas) {
    try {
      return [new Surface3D(canvas, scene), "webgl"];
    } catch (error) {
      console.warn(`WebGL unavailable, drawing with Canvas 2D: ${error.message}`);
      return [canvasRenderer(freshSurface(canvas.height), scene), "canvas2d"];
    }
  }
  return [canvasRenderer(canvas, scene), "canvas2d"];
}

function drawRamp() {
  const ramp = $("colour-ramp"), ctx = ramp.getContext("2d"), bytes = rampBytes();
  for (let y = 0; y < ramp.height; y++) {
    const k = 4 * Math.round((255 * (ramp.height - 1 - y)) / (ramp.height - 1));
    ctx.fillStyle = `rgb(${bytes[k]},${bytes[k + 1]},${bytes[k + 2]})`;
    ctx.fillRect(0, y, ramp.width, 1);
  }
}

function onScene(scene) {
  state.scene = scene;
  state.units = scene.units || PROBLEM_UNITS;
  state.pressed = null;
  $("title").textContent = `membrane view: ${scene.name}`;
  [state.renderer, state.rendererName] = chooseRenderer(scene);
  const extent = Math.max(...scene.hi.map((h, i) => h - scene.lo[i]));
  state.scaleBar = niceLength(extent);
  $("colour-unit").textContent = `(${state.units.length})`;
  const select = $("tool");
  select.replaceChildren(...(scene.tools || []).map((kind) => new Option(TOOL_NAMES[kind] || kind, kind)));
  $("probe-panel").hidden = !scene.live;
  $("hint").textContent = scene.live
    ? `live: press and drag on the ${scene.shape.length === 2 || scene.triangles ? "surface" : "rope"} to push the tool`
    : "film scene: playing at its dt";
  forcePlot.unit = state.units.force;
  updateTool();
}

function tool() { return $("tool").value || "tip"; }

function depth() {
  return state.scene ? Number($("depth").value) * state.scene.depth_max : 0;
}

function updateTool() {
  const grasp = tool() === "grasp";
  $("depth-label").textContent = grasp ? "lift" : "depth";
  $("force-name").textContent = grasp ? "holding force" : "contact force";
  $("depth-value").textContent = `${formatValue(depth() * state.units.factor, 3)} ${state.units.length}`;
}

function toolRadius() {
  const scene = state.scene;
  return ["sphere", "cylinder"].includes(tool()) ? scene.tool_radius : scene.radius;
}

// Pointer position -> scene coordinates (the renderer's own mapping).
function probeAt(event) {
  const rect = stage.getBoundingClientRect();
  const u = (event.clientX - rect.left) / rect.width, v = (event.clientY - rect.top) / rect.height;
  return { at: state.renderer.pick(u, v) };
}

let socket = null;

function send(message) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
}
state.send = send; // for tests: what the page would send

function pressMessage() {
  const at = state.pressed.at;
  return { type: "press", at, depth: depth(), radius: toolRadius(), tool: tool() };
}

function press(event) {
  if (!state.scene || !state.scene.live || !state.renderer) return;
  state.pressed = probeAt(event);
  send(pressMessage());
}

stage.addEventListener("pointerdown", (event) => {
  stage.setPointerCapture?.(event.pointerId);
  press(event);
});
stage.addEventListener("pointermove", (event) => { if (state.pressed) press(event); });
for (const kind of ["pointerup", "pointercancel"]) {
  stage.addEventListener(kind, () => { state.pressed = null; send({ type: "release" }); });
}
for (const id of ["depth", "tool"]) {
  $(id).addEventListener("input", () => {
    updateTool();
    if (state.pressed) send(pressMessage());
  });
}
$("reset").addEventListener("click", () => send({ type: "reset" }));

// Where a scene point is in the page (client pixels), for tests and scripted presses.
state.clientPoint = (x, y) => {
  const [px, py] = state.renderer.toScreen(x, y);
  const rect = stage.getBoundingClientRect(), canvas = $("surface");
  return [rect.left + (px * rect.width) / canvas.width, rect.top + (py * rect.height) / canvas.height];
};

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

// The tool as drawn: where the pointer presses, at the slider's depth, in its size.
function drawnTool() {
  if (!state.pressed) return null;
  return { kind: tool(), at: state.pressed.at, depth: depth(), radius: toolRadius() };
}

// Labels on the overlay: the scale bar, the heights' exaggeration, the tool.
function drawOverlay(view) {
  const ctx = overlay.getContext("2d"), { units, renderer } = state;
  ctx.clearRect(0, 0, overlay.width, overlay.height);
  const [[x0, y0], [x1, y1]] = renderer.scaleBarScreen(state.scaleBar);
  ctx.strokeStyle = "#fff";
  ctx.fillStyle = "#fff";
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(x0, y0); ctx.lineTo(x1, y1);
  ctx.moveTo(x0, y0 - 5); ctx.lineTo(x0, y0 + 5);
  ctx.moveTo(x1, y1 - 5); ctx.lineTo(x1, y1 + 5);
  ctx.stroke();
  ctx.font = "13px system-ui, sans-serif";
  state.scaleBarLabel = `${formatValue(state.scaleBar * units.factor)} ${units.length}`;
  ctx.fillText(state.scaleBarLabel, x0, y0 - 8);
  const note = renderer.exaggeration ? `heights x ${formatValue(renderer.exaggeration)}` : "";
  $("scale-note").textContent = note ? `${note}; tools drawn to scale` : "";
  if (view.tool) {
    const [px, py] = renderer.toScreen(...view.tool.at);
    const unit = units.physical ? ` ${units.length}` : "", t = view.tool;
    const size = t.radius > 0 ? `r ${formatValue(t.radius * units.factor)}${unit}, ` : "";
    const how = t.kind === "grasp" ? "held, lifted" : "deep";
    const label = `${t.kind} ${size}${formatValue(t.depth * units.factor)}${unit} ${how}`;
    const width = ctx.measureText(label).width;
    ctx.fillText(label, Math.max(4, Math.min(px + 14, overlay.width - width - 4)), Math.max(14, py - 14));
  }
}

function toolScreen(view) {
  if (!view.tool) return null;
  const { renderer } = state, [x, y] = [view.tool.at[0], view.tool.at[1]];
  const [px, py] = renderer.toolScreen ? renderer.toolScreen(view.tool) : renderer.toScreen(x, y);
  const [qx, qy] = renderer.toScreen(x + Math.max(view.tool.radius, 1e-12), y);
  const [cx, cy] = renderer.toScreen(x, y);
  return { x: px, y: py, r: Math.hypot(qx - cx, qy - cy) };
}

// The colour scale: the frame's own range, but at least 1 % of the slider's depth, widened
// downwards, so that a surface at rest within rounding (or a ringing of microns after a
// release) is not painted as a dent across the whole ramp.
function colourRange(z) {
  const range = frameRange(z), least = 0.01 * (state.scene?.depth_max || 0);
  if (range.hi - range.lo < least) range.lo = range.hi - least;
  return range;
}

// Draw every animation frame (the page's own counter measures the drawing rate).
let lastCount = performance.now(), drawsThen = 0, framesThen = 0;
function tick(now) {
  if (state.renderer && state.frame && state.frame.z.length === (state.scene?.shape || []).reduce((a, b) => a * b, 1)) {
    const z = state.frame.z, range = colourRange(z), view = { range, tool: drawnTool() };
    state.renderer.draw(z, view);
    state.drawn = { z, range, k: state.frame.k };
    state.toolScreen = toolScreen(view);
    drawOverlay(view);
    state.draws += 1;
    if (state.fresh) { state.framesDrawn += 1; state.fresh = false; }
    const { factor, force } = state.units;
    $("tick-max").textContent = formatValue(range.hi * factor);
    $("tick-min").textContent = formatValue(range.lo * factor);
    $("force").textContent = state.frame.live ? `${state.force.toPrecision(3)} ${force}` : "-";
    $("time").textContent = state.frame.t.toFixed(3);
    $("step").textContent = state.frame.k;
    forcePlot.seconds = state.frameFps > 0 ? forcePlot.values.length / state.frameFps : 0;
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

drawRamp();
connect();
requestAnimationFrame(tick);
