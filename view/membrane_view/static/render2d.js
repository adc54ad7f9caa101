// Canvas 2D renderers: a shaded heat map for a 2-D lattice, a curve for a rope.
// No WebGL needed (headless Chromium without a GPU draws these).

// A diverging colour map: blue (down) - near black (rest) - orange (up); s in [-1, 1].
function colour(s) {
  const a = Math.min(1, Math.abs(s));
  if (s < 0) return [30 + 40 * a, 60 + 120 * a, 90 + 165 * a];
  return [30 + 225 * a, 60 + 110 * a, 90 - 60 * a];
}

export class HeatMap {
  constructor(canvas, shape) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    [this.nx, this.ny] = shape;
    this.buffer = document.createElement("canvas");
    this.buffer.width = this.nx;
    this.buffer.height = this.ny;
    this.bctx = this.buffer.getContext("2d");
    this.image = this.bctx.createImageData(this.nx, this.ny);
    this.scale = 1e-12;
  }

  // z: Float32Array, row-major (nx, ny), z[i * ny + j] at (x_i, y_j); y up on screen.
  draw(z, probe) {
    const { nx, ny, image } = this;
    let peak = 0;
    for (let n = 0; n < z.length; n++) peak = Math.max(peak, Math.abs(z[n]));
    // The colour scale follows the peak up at once and down slowly (no flicker).
    this.scale = Math.max(peak, this.scale * 0.995, 1e-12);
    const inv = 1 / this.scale;
    const data = image.data;
    for (let i = 0; i < nx; i++) {
      for (let j = 0; j < ny; j++) {
        const n = i * ny + j;
        // Hill shading from the two slopes (light from the upper left).
        const dx = (z[Math.min(i + 1, nx - 1) * ny + j] - z[Math.max(i - 1, 0) * ny + j]) * inv;
        const dy = (z[i * ny + Math.min(j + 1, ny - 1)] - z[i * ny + Math.max(j - 1, 0)]) * inv;
        const shade = Math.max(0.35, Math.min(1.25, 0.85 - 0.6 * dx + 0.6 * dy));
        const [r, g, b] = colour(z[n] * inv);
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
    if (probe) {
      ctx.strokeStyle = "#fff";
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.arc(probe.px, probe.py, Math.max(4, probe.pr), 0, 2 * Math.PI);
      ctx.stroke();
    }
  }
}

export class Rope {
  // `xs`: each point's x in [0, 1] across the canvas (a point list's own), or null for a grid.
  constructor(canvas, shape, xs = null) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.n = shape[0];
    this.xs = xs;
    this.scale = 1e-12;
  }

  draw(z, probe) {
    const { ctx, canvas, n } = this;
    let peak = 0;
    for (let k = 0; k < z.length; k++) peak = Math.max(peak, Math.abs(z[k]));
    this.scale = Math.max(peak, this.scale * 0.995, 1e-12);
    const w = canvas.width, h = canvas.height, mid = h / 2, amp = 0.4 * h / this.scale;
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, w, h);
    ctx.strokeStyle = "#333";
    ctx.beginPath();
    ctx.moveTo(0, mid);
    ctx.lineTo(w, mid);
    ctx.stroke();
    ctx.strokeStyle = "#f90";
    ctx.lineWidth = 3;
    ctx.beginPath();
    for (let k = 0; k < n; k++) {
      const u = this.xs ? this.xs[k] : k / Math.max(n - 1, 1);
      const x = u * w, y = mid - z[k] * amp;
      if (k === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    }
    ctx.stroke();
    if (probe) {
      ctx.fillStyle = "#fff";
      ctx.fillRect(probe.px - 3, 0, 6, mid - 4);
    }
  }
}

// A membrane's point list: each point a disc at its (x, y), coloured by its displacement.
export class Scatter {
  constructor(canvas, points, lo, hi) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    const span = [Math.max(hi[0] - lo[0], 1e-12), Math.max(hi[1] - lo[1], 1e-12)];
    this.uv = points.map(([x, y]) => [(x - lo[0]) / span[0], (y - lo[1]) / span[1]]);
    this.scale = 1e-12;
  }

  draw(z, probe) {
    const { ctx, canvas, uv } = this;
    let peak = 0;
    for (let k = 0; k < z.length; k++) peak = Math.max(peak, Math.abs(z[k]));
    this.scale = Math.max(peak, this.scale * 0.995, 1e-12);
    const w = canvas.width, h = canvas.height, pad = 12;
    const r = Math.max(3, 0.5 * Math.min(w, h) / Math.sqrt(uv.length + 1));
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, w, h);
    uv.forEach(([u, v], k) => {
      const [red, green, blue] = colour(z[k] / this.scale);
      ctx.fillStyle = `rgb(${red},${green},${blue})`;
      ctx.beginPath();
      ctx.arc(pad + u * (w - 2 * pad), pad + v * (h - 2 * pad), r, 0, 2 * Math.PI);
      ctx.fill();
    });
    if (probe) {
      ctx.strokeStyle = "#fff";
      ctx.beginPath();
      ctx.arc(probe.px, probe.py, Math.max(4, probe.pr), 0, 2 * Math.PI);
      ctx.stroke();
    }
  }
}

// A small force/time plot: the last `capacity` samples.
export class ForcePlot {
  constructor(canvas, capacity = 300) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.values = [];
    this.capacity = capacity;
  }

  push(value) {
    this.values.push(Number.isFinite(value) ? value : 0);
    if (this.values.length > this.capacity) this.values.shift();
  }

  draw() {
    const { ctx, canvas, values } = this;
    const w = canvas.width, h = canvas.height;
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, w, h);
    const top = Math.max(1e-12, ...values);
    ctx.strokeStyle = "#6cf";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    values.forEach((v, k) => {
      const x = (k / this.capacity) * w, y = h - 4 - (v / top) * (h - 8);
      if (k === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    });
    ctx.stroke();
    ctx.fillStyle = "#aaa";
    ctx.fillText(`max ${top.toPrecision(3)}`, 4, 12);
  }
}
