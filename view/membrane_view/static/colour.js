// The colour scale both renderers and the colour bar share: each frame's own range (min to
// max) onto a sequential ramp (viridis' stops: dark violet at the deepest dent, yellow at the
// highest point), and the labels' formatting in the scene's units.

const STOPS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];

// s in [0, 1] -> [r, g, b] in 0..255.
export function ramp(s) {
  const x = Math.min(1, Math.max(0, Number.isFinite(s) ? s : 0.5)) * (STOPS.length - 1);
  const k = Math.min(STOPS.length - 2, Math.floor(x)), f = x - k;
  const a = STOPS[k], b = STOPS[k + 1];
  return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
}

// 256 x 1 RGBA of the ramp (the WebGL surface's texture, the colour bar's image).
export function rampBytes() {
  const bytes = new Uint8Array(4 * 256);
  for (let k = 0; k < 256; k++) {
    const [r, g, b] = ramp(k / 255);
    bytes.set([Math.round(r), Math.round(g), Math.round(b), 255], 4 * k);
  }
  return bytes;
}

// The frame's range; a flat frame (at rest) maps to the ramp's middle.
export function frameRange(z) {
  let lo = Infinity, hi = -Infinity;
  for (let k = 0; k < z.length; k++) {
    const v = z[k];
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  if (!Number.isFinite(lo)) { lo = 0; hi = 0; }
  return { lo, hi };
}

// A value shown in the scene's display units, to `digits` significant digits.
export function formatValue(value, digits = 2) {
  if (!Number.isFinite(value)) return "-";
  if (value === 0) return "0";
  return Number(value.toPrecision(digits)).toString();
}

// A scale bar's length: 1, 2 or 5 times a power of ten, near a fifth of the extent.
export function niceLength(extent) {
  const target = extent / 5, power = 10 ** Math.floor(Math.log10(target));
  for (const m of [5, 2, 1]) if (m * power <= target) return m * power;
  return power;
}
