// Canvas 2D renderers, the fallback where WebGL is missing (and ?renderer=canvas): a shaded
// heat map for a 2-D lattice, a curve for a rope, a scatter for a membrane's point list. They
// colour by the frame's own range (colour.js), draw the pressing tool's outline in its size,
// and map the pointer to scene coordinates (`pick`) as the 3-D surface does.
import { ramp } from "./colour.js";

const TOOL = "rgba(235, 238, 245, 0.9)";

// Scene box -> canvas fractions, and back (y up on screen).
class Box {
  constructor(scene, pad = 0) {
    this.lo = scene.lo;
    this.hi = scene.hi;
    this.pad = pad;
    this.span = [Math.max(scene.hi[0] - scene.lo[0], 1e-12),
      Math.max((scene.hi[1] ?? 1) - (scene.lo[1] ?? 0), 1e-12)];
  }

  toScreen(canvas, x, y) {
    const { lo, span, pad } = this, w = canvas.width - 2 * pad, h = canvas.height - 2 * pad;
    const v = y == null ? 0.5 : (y - lo[1]) / span[1];
    return [pad + ((x - lo[0]) / span[0]) * w, pad + (1 - v) * h];
  }

  pick(canvas, u, v) {
    const { lo, span, pad } = this;
    const fu = (u * canvas.width - pad) / (canvas.width - 2 * pad);
    const fv = 1 - (v * canvas.height - pad) / (canvas.height - 2 * pad);
    const clamp = (t) => Math.min(1, Math.max(0, t));
    const at = [lo[0] + clamp(fu) * span[0]];
    if (lo.length === 2) at.push(lo[1] + clamp(fv) * span[1]);
    return at;
  }

  pixels(canvas, length) {
    return (length / this.span[0]) * (canvas.width - 2 * this.pad);
  }
}

// What the three Canvas renderers share: the pointer and the labels through their Box.
class BoxRenderer {
  toScreen(x, y) { return this.box.toScreen(this.canvas, x, y); }

  pick(u, v) { return this.box.pick(this.canvas, u, v); }

  scaleBarScreen(length) {
    const { canvas } = this, y = canvas.height - 16, x0 = 16;
    return [[x0, y], [x0 + this.box.pixels(canvas, length), y]];
  }
}

// The tool seen from above: its outline in its radius; a grasp as a cross ("held").
function toolOutline(ctx, tool, cx, cy, pr) {
  ctx.strokeStyle = TOOL;
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.arc(cx, cy, Math.max(4, pr), 0, 2 * Math.PI);
  ctx.stroke();
  if (tool.kind === "grasp") {
    ctx.beginPath();
    ctx.moveTo(cx - 8, cy - 8); ctx.lineTo(cx + 8, cy + 8);
    ctx.moveTo(cx + 8, cy - 8); ctx.lineTo(cx - 8, cy + 8);
    ctx.stroke();
  }
}

export class HeatMap extends BoxRenderer {
  constructor(canvas, scene) {
    super();
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    [this.nx, this.ny] = scene.shape;
    this.box = new Box(scene);
    this.buffer = document.createElement("canvas");
    this.buffer.width = this.nx;
    this.buffer.height = this.ny;
    this.bctx = this.buffer.getContext("2d");
    this.image = this.bctx.createImageData(this.nx, this.ny);
  }

  // z: Float32Array, row-major (nx, ny), z[i * ny + j] at (x_i, y_j); y up on screen.
  draw(z, view) {
    const { nx, ny, image } = this, { lo, hi } = view.range;
    const span = hi - lo, inv = span > 0 ? 1 / span : 0;
    const data = image.data;
    for (let i = 0; i < nx; i++) {
      for (let j = 0; j < ny; j++) {
        const n = i * ny + j;
        // Hill shading from the two slopes (light from the upper left).
        const dx = (z[Math.min(i + 1, nx - 1) * ny + j] - z[Math.max(i - 1, 0) * ny + j]) * inv;
        const dy = (z[i * ny + Math.min(j + 1, ny - 1)] - z[i * ny + Math.max(j - 1, 0)]) * inv;
        const shade = Math.max(0.55, Math.min(1.2, 0.9 - 0.5 * dx + 0.5 * dy));
        const [r, g, b] = ramp(span > 0 ? (z[n] - lo) * inv : 0.5);
        const p = 4 * ((ny - 1 - j) * nx + i);
        data[p] = r * shade;
        data[p + 1] = g * shade;
        data[p + 2] = b * shade;
        data[p + 3] = 255;
      }
    }
    this.bctx.putImageData(image, 0, 0);
    const { ctx, canvas } = this;
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(this.buffer, 0, 0, canvas.width, canvas.height);
    if (view.tool) {
      const [cx, cy] = this.toScreen(...view.tool.at);
      toolOutline(ctx, view.tool, cx, cy, this.box.pixels(canvas, view.tool.radius));
    }
  }
}

export class Rope extends BoxRenderer {
  // `xs`: each point's x in scene units (a point list's own), or null for a grid.
  constructor(canvas, scene, xs = null) {
    super();
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.n = scene.shape[0];
    this.box = new Box(scene);
    this.xs = xs;
    this.scale = 1e-12;
  }

  draw(z, view) {
    const { ctx, canvas, n } = this;
    let peak = 0;
    for (let k = 0; k < z.length; k++) peak = Math.max(peak, Math.abs(z[k]));
    this.scale = Math.max(peak, this.scale * 0.995, 1e-12);
    const w = canvas.width, h = canvas.height, mid = h / 2, amp = (0.4 * h) / this.scale;
    ctx.fillStyle = "#0a0a0d";
    ctx.fillRect(0, 0, w, h);
    ctx.strokeStyle = "#333";
    ctx.beginPath();
    ctx.moveTo(0, mid);
    ctx.lineTo(w, mid);
    ctx.stroke();
    ctx.strokeStyle = "#fde725";
    ctx.lineWidth = 3;
    ctx.beginPath();
    const { lo, span } = this.box;
    for (let k = 0; k < n; k++) {
      const u = this.xs ? (this.xs[k] - lo[0]) / span[0] : k / Math.max(n - 1, 1);
      const x = u * w, y = mid - z[k] * amp;
      if (k === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    }
    ctx.stroke();
    if (view.tool) {
      const [px] = this.toScreen(view.tool.at[0]);
      const bottom = mid + view.tool.depth * amp * (view.tool.kind === "grasp" ? -1 : 1);
      ctx.fillStyle = view.tool.kind === "grasp" ? "rgba(255, 140, 64, 0.85)" : TOOL;
      ctx.fillRect(px - 3, 0, 6, Math.max(0, bottom - 3));
    }
  }

  toScreen(x) { return this.box.toScreen(this.canvas, x, null); }
}

// A membrane's point list: each point a disc at its (x, y), coloured by its displacement.
export class Scatter extends BoxRenderer {
  constructor(canvas, scene) {
    super();
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.points = scene.points;
    this.box = new Box(scene, 12);
  }

  draw(z, view) {
    const { ctx, canvas, points } = this, { lo, hi } = view.range;
    const w = canvas.width, h = canvas.height;
    const r = Math.max(3, (0.5 * Math.min(w, h)) / Math.sqrt(points.length + 1));
    ctx.fillStyle = "#0a0a0d";
    ctx.fillRect(0, 0, w, h);
    points.forEach(([x, y], k) => {
      const [red, green, blue] = ramp(hi > lo ? (z[k] - lo) / (hi - lo) : 0.5);
      const [px, py] = this.toScreen(x, y);
      ctx.fillStyle = `rgb(${red},${green},${blue})`;
      ctx.beginPath();
      ctx.arc(px, py, r, 0, 2 * Math.PI);
      ctx.fill();
    });
    if (view.tool) {
      const [cx, cy] = this.toScreen(...view.tool.at);
      toolOutline(ctx, view.tool, cx, cy, this.box.pixels(canvas, view.tool.radius));
    }
  }
}

// The force against time: the last `capacity` samples, its axis in the force's unit.
export class ForcePlot {
  constructor(canvas, capacity = 300) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.values = [];
    this.capacity = capacity;
    this.unit = "";
    this.seconds = 0;
  }

  push(value) {
    this.values.push(Number.isFinite(value) ? value : 0);
    if (this.values.length > this.capacity) this.values.shift();
  }

  draw() {
    const { ctx, canvas, values } = this;
    const w = canvas.width, h = canvas.height;
    ctx.fillStyle = "#0a0a0d";
    ctx.fillRect(0, 0, w, h);
    const top = Math.max(1e-12, ...values), bottom = Math.min(0, ...values);
    const y = (v) => h - 14 - ((v - bottom) / (top - bottom)) * (h - 28);
    ctx.strokeStyle = "#333";
    ctx.beginPath();
    ctx.moveTo(0, y(0));
    ctx.lineTo(w, y(0));
    ctx.stroke();
    ctx.strokeStyle = "#6cf";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    values.forEach((v, k) => {
      const x = (k / this.capacity) * w;
      if (k === 0) ctx.moveTo(x, y(v)); else ctx.lineTo(x, y(v));
    });
    ctx.stroke();
    ctx.fillStyle = "#aaa";
    ctx.fillText(`max ${top.toPrecision(3)} ${this.unit}`, 4, 11);
    if (this.seconds > 0) ctx.fillText(`last ${this.seconds.toFixed(1)} s`, w - 64, h - 3);
  }
}
