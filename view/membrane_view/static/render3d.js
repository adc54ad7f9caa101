// The shaded 3-D surface in raw WebGL 1 (no library): the lattice's triangles (a grid's cells,
// or describe's triangles on a physical scene's tissue), heights from each frame, coloured by
// the frame's own range (colour.js), normals recomputed per frame, one directional light, and
// the tool that presses drawn where it presses. The page's default wherever WebGL exists;
// the Canvas 2D heat map (render2d.js) is the fallback.
//
// Plane coordinates: the scene's (x, y) centred and divided by half the longer side, so the
// tissue keeps its aspect. Heights are exaggerated by `exaggeration` (a 1, 2 or 5 times a power
// of ten, said on the page) so that a dent of the slider's depth is visible; tools are drawn
// to scale in the plane, their lowest point at the exaggerated depth (the dent's floor).
import { rampBytes } from "./colour.js";

const SURFACE_VERTEX = `
attribute vec2 xy; attribute float h; attribute float c; attribute vec3 normal;
uniform mat4 mvp; varying float shade; varying float v;
void main() {
  v = c;
  gl_Position = mvp * vec4(xy, h, 1.0);
  shade = 0.4 + 0.6 * abs(dot(normalize(normal), normalize(vec3(-0.4, -0.6, 0.8))));
}`;
const SURFACE_FRAGMENT = `
precision mediump float; uniform sampler2D ramp; varying float shade; varying float v;
void main() { gl_FragColor = vec4(texture2D(ramp, vec2(v, 0.5)).rgb * shade, 1.0); }`;
const SOLID_VERTEX = `
attribute vec3 position; attribute vec3 normal; uniform mat4 mvp; uniform mat4 model;
varying float shade;
void main() {
  gl_Position = mvp * model * vec4(position, 1.0);
  shade = 0.45 + 0.55 * max(dot(normalize(normal), normalize(vec3(-0.4, -0.6, 0.8))), 0.0);
}`;
const SOLID_FRAGMENT = `
precision mediump float; uniform vec4 colour; varying float shade;
void main() { gl_FragColor = vec4(colour.rgb * shade, colour.a); }`;

// Translucent, so the dent under the tool stays visible; back faces culled (one layer blended).
const TOOL_COLOUR = [0.7, 0.74, 0.8, 0.3];
const HELD_COLOUR = [1.0, 0.55, 0.25, 0.8];
const HEIGHT_SHARE = 0.6; // the slider's deepest dent, in plane units (half the side is 1)

function multiply(a, b) { // column-major 4 x 4
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
    let v = 0;
    for (let k = 0; k < 4; k++) v += a[k * 4 + r] * b[c * 4 + k];
    out[c * 4 + r] = v;
  }
  return out;
}

function perspective(fov, aspect, near, far) {
  const f = 1 / Math.tan(fov / 2), nf = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1,
    0, 0, 2 * far * near * nf, 0]);
}

function lookAt(eye, target, up) {
  const sub = (a, b) => a.map((v, i) => v - b[i]);
  const norm = (a) => { const l = Math.hypot(...a); return a.map((v) => v / l); };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
    a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const z = norm(sub(eye, target)), x = norm(cross(up, z)), y = cross(z, x);
  return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
    -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
}

// Translate to (x, y, z), then scale by (sx, sy, sz).
function placed(x, y, z, sx, sy, sz) {
  return new Float32Array([sx, 0, 0, 0, 0, sy, 0, 0, 0, 0, sz, 0, x, y, z, 1]);
}

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
  return shader;
}

function program(gl, vertex, fragment) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vertex));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fragment));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  return p;
}

// A unit sphere (radius 1 at the origin) as triangles: positions, which are its normals too.
function sphereMesh(rings = 14, sectors = 24) {
  const out = [];
  const at = (r, s) => {
    const th = (Math.PI * r) / rings, ph = (2 * Math.PI * s) / sectors;
    return [Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th)];
  };
  for (let r = 0; r < rings; r++) for (let s = 0; s < sectors; s++) {
    const a = at(r, s), b = at(r + 1, s), c = at(r, s + 1), d = at(r + 1, s + 1);
    out.push(...a, ...b, ...c, ...c, ...b, ...d);
  }
  const positions = new Float32Array(out);
  return { positions, normals: positions };
}

// A unit cylinder (radius 1, z from 0 to 1) with both caps.
function cylinderMesh(sectors = 32) {
  const p = [], n = [];
  for (let s = 0; s < sectors; s++) {
    const a = (2 * Math.PI * s) / sectors, b = (2 * Math.PI * (s + 1)) / sectors;
    const [ca, sa, cb, sb] = [Math.cos(a), Math.sin(a), Math.cos(b), Math.sin(b)];
    p.push(ca, sa, 0, cb, sb, 0, ca, sa, 1, ca, sa, 1, cb, sb, 0, cb, sb, 1);
    n.push(ca, sa, 0, cb, sb, 0, ca, sa, 0, ca, sa, 0, cb, sb, 0, cb, sb, 0);
    p.push(0, 0, 0, cb, sb, 0, ca, sa, 0, 0, 0, 1, ca, sa, 1, cb, sb, 1);
    n.push(0, 0, -1, 0, 0, -1, 0, 0, -1, 0, 0, 1, 0, 0, 1, 0, 0, 1);
  }
  return { positions: new Float32Array(p), normals: new Float32Array(n) };
}

// 1, 2 or 5 times a power of ten, at most x.
function niceBelow(x) {
  const power = 10 ** Math.floor(Math.log10(x));
  for (const m of [5, 2, 1]) if (m * power <= x) return m * power;
  return power;
}

export class Surface3D {
  // scene: the bridge's scene message (shape, lo, hi, depth_max, points, triangles).
  constructor(canvas, scene) {
    const gl = canvas.getContext("webgl", { antialias: false });
    if (!gl) throw new Error("no WebGL");
    const grid = scene.shape.length === 2;
    if (!grid && !(scene.triangles && scene.points && scene.points[0]?.length === 2)) {
      throw new Error("a surface needs a 2-D grid or triangles");
    }
    this.gl = gl;
    this.canvas = canvas;
    this.scene = scene;
    const { lo, hi } = scene;
    this.centre = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2];
    this.half = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-12) / 2;
    this.xy = this.planePoints(scene, grid);
    const n = this.xy.length / 2;
    if (n > 65536) throw new Error("lattice too large for 16-bit indices");
    const indices = scene.triangles ? Uint16Array.from(scene.triangles) : gridIndices(...scene.shape);
    this.indices = indices;
    this.surface = program(gl, SURFACE_VERTEX, SURFACE_FRAGMENT);
    this.solid = program(gl, SOLID_VERTEX, SOLID_FRAGMENT);
    this.indexBuffer = this.buffer(gl.ELEMENT_ARRAY_BUFFER, indices, gl.STATIC_DRAW);
    this.xyBuffer = this.buffer(gl.ARRAY_BUFFER, this.xy, gl.STATIC_DRAW);
    this.heights = new Float32Array(n);
    this.colours = new Float32Array(n);
    this.normals = new Float32Array(3 * n);
    this.hBuffer = this.buffer(gl.ARRAY_BUFFER, this.heights, gl.DYNAMIC_DRAW);
    this.cBuffer = this.buffer(gl.ARRAY_BUFFER, this.colours, gl.DYNAMIC_DRAW);
    this.nBuffer = this.buffer(gl.ARRAY_BUFFER, this.normals, gl.DYNAMIC_DRAW);
    this.meshes = { sphere: this.mesh(sphereMesh()), cylinder: this.mesh(cylinderMesh()) };
    const texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, texture);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 256, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, rampBytes());
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    const aspect = canvas.width / canvas.height;
    this.mvp = multiply(perspective(0.72, aspect, 0.1, 20), lookAt([0, -3.2, 2.6], [0, 0.0, -0.2], [0, 0, 1]));
    this.peak = 0;
    this.exaggeration = 1;
    gl.enable(gl.DEPTH_TEST);
  }

  // Each lattice point in plane coordinates.
  planePoints(scene, grid) {
    const { lo, hi } = scene, xy = [];
    if (grid && !scene.points) {
      const [nx, ny] = scene.shape;
      for (let i = 0; i < nx; i++) for (let j = 0; j < ny; j++) {
        xy.push(...this.toPlane(lo[0] + (i * (hi[0] - lo[0])) / (nx - 1),
          lo[1] + (j * (hi[1] - lo[1])) / (ny - 1)));
      }
    } else {
      for (const [x, y] of scene.points) xy.push(...this.toPlane(x, y));
    }
    return new Float32Array(xy);
  }

  toPlane(x, y) {
    return [(x - this.centre[0]) / this.half, (y - this.centre[1]) / this.half];
  }

  buffer(target, data, usage) {
    const { gl } = this, buffer = gl.createBuffer();
    gl.bindBuffer(target, buffer);
    gl.bufferData(target, data, usage);
    return buffer;
  }

  mesh({ positions, normals }) {
    const { gl } = this;
    return {
      positions: this.buffer(gl.ARRAY_BUFFER, positions, gl.STATIC_DRAW),
      normals: this.buffer(gl.ARRAY_BUFFER, normals, gl.STATIC_DRAW),
      count: positions.length / 3,
    };
  }

  bind(programObject, name, buffer, size) {
    const { gl } = this, location = gl.getAttribLocation(programObject, name);
    if (location < 0) return;
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.enableVertexAttribArray(location);
    gl.vertexAttribPointer(location, size, gl.FLOAT, false, 0, 0);
  }

  // Displayed heights: true ones times the exaggeration, in plane units. It follows the peak
  // up at once and down slowly, never below what shows the slider's deepest dent.
  updateExaggeration(z) {
    let peak = 0;
    for (let k = 0; k < z.length; k++) peak = Math.max(peak, Math.abs(z[k]));
    this.peak = Math.max(peak, this.peak * 0.995);
    const reach = Math.max(this.peak, this.scene.depth_max || 0, 1e-12);
    this.exaggeration = niceBelow((HEIGHT_SHARE * this.half) / reach);
    return this.exaggeration / this.half; // plane units per scene unit of height
  }

  // view: {range: {lo, hi}, tool: {kind, at, depth, radius} | null}
  draw(z, view) {
    const { gl, heights, colours, normals, xy, indices } = this;
    const k = this.updateExaggeration(z), span = view.range.hi - view.range.lo;
    this.k = k;
    for (let m = 0; m < z.length; m++) {
      heights[m] = z[m] * k;
      colours[m] = span > 0 ? (z[m] - view.range.lo) / span : 0.5;
    }
    normals.fill(0);
    for (let t = 0; t < indices.length; t += 3) {
      const a = indices[t], b = indices[t + 1], c = indices[t + 2];
      const ux = xy[2 * b] - xy[2 * a], uy = xy[2 * b + 1] - xy[2 * a + 1], uz = heights[b] - heights[a];
      const vx = xy[2 * c] - xy[2 * a], vy = xy[2 * c + 1] - xy[2 * a + 1], vz = heights[c] - heights[a];
      const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
      for (const p of [a, b, c]) { normals[3 * p] += nx; normals[3 * p + 1] += ny; normals[3 * p + 2] += nz; }
    }
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.clearColor(0.04, 0.04, 0.05, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.disable(gl.BLEND);
    gl.depthMask(true);
    gl.useProgram(this.surface);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.surface, "mvp"), false, this.mvp);
    gl.uniform1i(gl.getUniformLocation(this.surface, "ramp"), 0);
    this.bind(this.surface, "xy", this.xyBuffer, 2);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.hBuffer);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, heights);
    this.bind(this.surface, "h", this.hBuffer, 1);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.cBuffer);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, colours);
    this.bind(this.surface, "c", this.cBuffer, 1);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.nBuffer);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, normals);
    this.bind(this.surface, "normal", this.nBuffer, 3);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.indexBuffer);
    gl.drawElements(gl.TRIANGLES, indices.length, gl.UNSIGNED_SHORT, 0);
    this.disable(this.surface, ["xy", "h", "c", "normal"]);
    if (view.tool) this.drawTool(view.tool, k);
  }

  disable(programObject, names) {
    const { gl } = this;
    for (const name of names) {
      const location = gl.getAttribLocation(programObject, name);
      if (location >= 0) gl.disableVertexAttribArray(location);
    }
  }

  // The scale bar's ends on the canvas (pixels): `length` (scene units) along the front
  // edge at rest height (a straight line projects to one, so the page draws it flat).
  scaleBarScreen(length) {
    const y = -1.12, x0 = -1, x1 = x0 + length / this.half;
    return [this.screen(x0, y, 0), this.screen(x1, y, 0)];
  }

  // The tool in its shape and size, its lowest point at the (exaggerated) depth it presses
  // to; a grasp as two jaws closed on the tissue at the height it holds.
  drawTool(tool, k) {
    const { gl } = this;
    const [x, y] = this.toPlane(tool.at[0], tool.at[1] ?? this.centre[1]);
    const r = Math.max(tool.radius / this.half, 0.015);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    gl.depthMask(false);
    gl.enable(gl.CULL_FACE);
    if (tool.kind === "grasp") {
      const h = tool.depth * k, jaw = 0.025, gap = r + 0.035;
      for (const side of [-1, 1]) {
        this.solidMesh("cylinder", placed(x + side * gap, y, h - 0.02, jaw, jaw * 2, 0.3), HELD_COLOUR);
      }
      this.solidMesh("cylinder", placed(x, y, h + 0.28, gap + jaw, jaw, 0.04), HELD_COLOUR);
    } else {
      const bottom = -tool.depth * k;
      if (tool.kind === "cylinder") {
        this.solidMesh("cylinder", placed(x, y, bottom, r, r, 1.5 * r), TOOL_COLOUR);
      } else if (tool.kind === "sphere") {
        this.solidMesh("sphere", placed(x, y, bottom + r, r, r, r), TOOL_COLOUR);
      } else { // the soft tip: a rounded end on a shaft
        const tip = Math.max(r, 0.03);
        this.solidMesh("sphere", placed(x, y, bottom + tip, tip, tip, tip), TOOL_COLOUR);
        this.solidMesh("cylinder", placed(x, y, bottom + tip, 0.5 * tip, 0.5 * tip, 0.6), TOOL_COLOUR);
      }
    }
    gl.disable(gl.CULL_FACE);
    gl.depthMask(true);
    gl.disable(gl.BLEND);
  }

  solidMesh(name, model, colour) {
    const { gl } = this, mesh = this.meshes[name];
    gl.useProgram(this.solid);
    this.bind(this.solid, "position", mesh.positions, 3);
    this.bind(this.solid, "normal", mesh.normals, 3);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.solid, "mvp"), false, this.mvp);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.solid, "model"), false, model);
    gl.uniform4fv(gl.getUniformLocation(this.solid, "colour"), colour);
    gl.drawArrays(gl.TRIANGLES, 0, mesh.count);
    this.disable(this.solid, ["position", "normal"]);
  }

  // Plane point (x, y, height) -> canvas pixels.
  screen(x, y, h) {
    const m = this.mvp;
    const w = m[3] * x + m[7] * y + m[11] * h + m[15];
    const sx = (m[0] * x + m[4] * y + m[8] * h + m[12]) / w;
    const sy = (m[1] * x + m[5] * y + m[9] * h + m[13]) / w;
    return [((sx + 1) / 2) * this.canvas.width, ((1 - sy) / 2) * this.canvas.height];
  }

  // Where the tool meets the tissue on the canvas: its lowest point (a grasp's jaws).
  toolScreen(tool) {
    const [x, y] = this.toPlane(tool.at[0], tool.at[1] ?? this.centre[1]);
    const h = (tool.kind === "grasp" ? 1 : -1) * tool.depth * (this.k || 0);
    return this.screen(x, y, h);
  }

  // A scene point at rest height -> canvas pixels.
  toScreen(x, y) {
    const [px, py] = this.toPlane(x, y ?? this.centre[1]);
    return this.screen(px, py, 0);
  }

  // The pointer (u, v in [0, 1] of the canvas) on the rest plane: scene coordinates, kept in
  // the lattice's box. The ray through the pixel meets the plane h = 0 where two linear
  // equations in (x, y) hold.
  pick(u, v) {
    const m = this.mvp, sx = 2 * u - 1, sy = 1 - 2 * v;
    const a = m[0] - sx * m[3], b = m[4] - sx * m[7], e = sx * m[15] - m[12];
    const c = m[1] - sy * m[3], d = m[5] - sy * m[7], f = sy * m[15] - m[13];
    const det = a * d - b * c;
    const x = (e * d - b * f) / det, y = (a * f - e * c) / det;
    const { lo, hi } = this.scene;
    const clamp = (value, low, high) => Math.min(high, Math.max(low, value));
    return [clamp(this.centre[0] + x * this.half, lo[0], hi[0]),
      clamp(this.centre[1] + y * this.half, lo[1], hi[1])];
  }
}

function gridIndices(nx, ny) {
  const indices = new Uint16Array(6 * (nx - 1) * (ny - 1));
  let p = 0;
  for (let i = 0; i < nx - 1; i++) for (let j = 0; j < ny - 1; j++) {
    const a = i * ny + j, b = a + ny, c = a + 1, d = b + 1;
    indices.set([a, b, c, c, b, d], p);
    p += 6;
  }
  return indices;
}
