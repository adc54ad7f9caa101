// A shaded 3-D surface in raw WebGL 1 (no library): the lattice as triangles, heights from each
// frame, normals recomputed per frame, one directional light. Opt-in with ?renderer=webgl; the
// page falls back to Canvas 2D (render2d.js) when WebGL is unavailable.

const VERTEX = `
attribute vec2 xy; attribute float h; attribute vec3 normal;
uniform mat4 mvp; uniform float scale;
varying float shade; varying float s;
void main() {
  s = h * scale;
  gl_Position = mvp * vec4(xy, 0.35 * s, 1.0);
  shade = 0.35 + 0.65 * max(dot(normalize(normal), normalize(vec3(-0.4, -0.6, 0.8))), 0.0);
}`;
const FRAGMENT = `
precision mediump float; varying float shade; varying float s;
void main() {
  float a = clamp(abs(s), 0.0, 1.0);
  vec3 down = vec3(0.12 + 0.16 * a, 0.24 + 0.47 * a, 0.35 + 0.65 * a);
  vec3 up = vec3(0.12 + 0.88 * a, 0.24 + 0.43 * a, 0.35 - 0.24 * a);
  gl_FragColor = vec4((s < 0.0 ? down : up) * shade, 1.0);
}`;

function multiply(a, b) {  // column-major 4 x 4
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

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
  return shader;
}

export class Surface3D {
  constructor(canvas, shape) {
    const gl = canvas.getContext("webgl", { preserveDrawingBuffer: true });
    if (!gl || shape.length !== 2) throw new Error("no WebGL (or not a 2-D lattice)");
    this.gl = gl;
    this.canvas = canvas;
    [this.nx, this.ny] = shape;
    const { nx, ny } = this, n = nx * ny;
    if (n > 65536) throw new Error("lattice too large for 16-bit indices");
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(program);
    gl.useProgram(program);
    this.program = program;
    // Plane coordinates in [-1, 1]^2: vertex i * ny + j at (x_i, y_j).
    this.xy = new Float32Array(2 * n);
    for (let i = 0; i < nx; i++) for (let j = 0; j < ny; j++) {
      this.xy[2 * (i * ny + j)] = -1 + (2 * i) / (nx - 1);
      this.xy[2 * (i * ny + j) + 1] = -1 + (2 * j) / (ny - 1);
    }
    const indices = new Uint16Array(6 * (nx - 1) * (ny - 1));
    let p = 0;
    for (let i = 0; i < nx - 1; i++) for (let j = 0; j < ny - 1; j++) {
      const a = i * ny + j, b = a + ny, c = a + 1, d = b + 1;
      indices.set([a, b, c, c, b, d], p);
      p += 6;
    }
    this.count = indices.length;
    this.buffer(gl.ELEMENT_ARRAY_BUFFER, indices, gl.STATIC_DRAW);
    this.attribute("xy", this.buffer(gl.ARRAY_BUFFER, this.xy, gl.STATIC_DRAW), 2);
    this.hBuffer = this.attribute("h", this.buffer(gl.ARRAY_BUFFER, new Float32Array(n), gl.DYNAMIC_DRAW), 1);
    this.normals = new Float32Array(3 * n);
    this.nBuffer = this.attribute("normal", this.buffer(gl.ARRAY_BUFFER, this.normals, gl.DYNAMIC_DRAW), 3);
    const aspect = canvas.width / canvas.height;
    this.mvp = multiply(perspective(0.75, aspect, 0.1, 20), lookAt([0, -2.4, 1.9], [0, 0.05, 0], [0, 0, 1]));
    gl.uniformMatrix4fv(gl.getUniformLocation(program, "mvp"), false, this.mvp);
    this.scaleLocation = gl.getUniformLocation(program, "scale");
    this.scale = 1e-12;
    gl.enable(gl.DEPTH_TEST);
  }

  buffer(target, data, usage) {
    const { gl } = this, buffer = gl.createBuffer();
    gl.bindBuffer(target, buffer);
    gl.bufferData(target, data, usage);
    return buffer;
  }

  attribute(name, buffer, size) {
    const { gl } = this, location = gl.getAttribLocation(this.program, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.enableVertexAttribArray(location);
    gl.vertexAttribPointer(location, size, gl.FLOAT, false, 0, 0);
    return buffer;
  }

  draw(z) {
    const { gl, nx, ny, normals } = this;
    let peak = 0;
    for (let k = 0; k < z.length; k++) peak = Math.max(peak, Math.abs(z[k]));
    this.scale = Math.max(peak, this.scale * 0.995, 1e-12);
    const k = 0.35 / this.scale, hx = 2 / (nx - 1), hy = 2 / (ny - 1);
    for (let i = 0; i < nx; i++) for (let j = 0; j < ny; j++) {
      const dzx = (z[Math.min(i + 1, nx - 1) * ny + j] - z[Math.max(i - 1, 0) * ny + j]) * k / (2 * hx);
      const dzy = (z[i * ny + Math.min(j + 1, ny - 1)] - z[i * ny + Math.max(j - 1, 0)]) * k / (2 * hy);
      const q = 3 * (i * ny + j);
      normals[q] = -dzx; normals[q + 1] = -dzy; normals[q + 2] = 1;
    }
    gl.bindBuffer(gl.ARRAY_BUFFER, this.hBuffer);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, z);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.nBuffer);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, normals);
    gl.uniform1f(this.scaleLocation, 1 / this.scale);
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.clearColor(0, 0, 0, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.drawElements(gl.TRIANGLES, this.count, gl.UNSIGNED_SHORT, 0);
  }

  // The lattice point nearest to the pointer (u, v in [0, 1] of the canvas) on the rest plane:
  // fractions (a, b) in [0, 1] along x and y.
  pick(u, v) {
    const { mvp, xy } = this;
    let best = Infinity, a = 0.5, b = 0.5;
    for (let m = 0; m < xy.length / 2; m++) {
      const x = xy[2 * m], y = xy[2 * m + 1];
      const w = mvp[3] * x + mvp[7] * y + mvp[15];
      const sx = ((mvp[0] * x + mvp[4] * y + mvp[12]) / w + 1) / 2;
      const sy = (1 - (mvp[1] * x + mvp[5] * y + mvp[13]) / w) / 2;
      const d = (sx - u) ** 2 + (sy - v) ** 2;
      if (d < best) { best = d; a = (x + 1) / 2; b = (y + 1) / 2; }
    }
    return [a, b];
  }
}
