// The bridge's binary frames (membrane_view/wire.py): a 32-byte header, then float32 z.
export const HEADER_SIZE = 32;
const MAGIC = "MBF1";

export function decodeFrame(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== MAGIC) throw new Error(`bad frame magic ${magic}`);
  const n = view.getUint32(20, true);
  const flags = view.getUint32(28, true);
  return {
    k: view.getUint32(4, true),
    t: view.getFloat64(8, true),
    force: view.getFloat32(16, true),
    bridgeUs: view.getFloat32(24, true),
    live: (flags & 1) !== 0,
    contact: (flags & 2) !== 0,
    z: new Float32Array(buffer, HEADER_SIZE, n),
  };
}
