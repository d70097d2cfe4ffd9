// Per-frame geometry work moved off the page's main thread (issue 44): vertex normals and the
// bounding sphere of new positions, as three.js computes them (area-weighted face normals summed
// per vertex; the bounding box's centre and the farthest vertex from it), so that the page only
// uploads them. Pure.

/** Area-weighted vertex normals of `p` (3 per vertex) into `out` (same length), normalised. */
export function vertexNormals(p: ArrayLike<number>, indices: ArrayLike<number>, out: Float32Array): Float32Array {
  out.fill(0);
  for (let f = 0; f + 2 < indices.length; f += 3) {
    const a = indices[f] * 3, b = indices[f + 1] * 3, c = indices[f + 2] * 3;
    const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
    const vx = p[c] - p[a], vy = p[c + 1] - p[a + 1], vz = p[c + 2] - p[a + 2];
    // (c - b) x (a - b), as three.js: the same orientation as u x v.
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    out[a] += nx; out[a + 1] += ny; out[a + 2] += nz;
    out[b] += nx; out[b + 1] += ny; out[b + 2] += nz;
    out[c] += nx; out[c + 1] += ny; out[c + 2] += nz;
  }
  for (let i = 0; i < out.length; i += 3) {
    const n = Math.hypot(out[i], out[i + 1], out[i + 2]);
    if (n > 0) { out[i] /= n; out[i + 1] /= n; out[i + 2] /= n; }
  }
  return out;
}

/** The bounding sphere three.js computes: the bounding box's centre and the largest distance of
 * a vertex from it. */
export function boundingSphere(p: ArrayLike<number>): { center: [number, number, number]; radius: number } {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < p.length; i += 3) {
    for (let c = 0; c < 3; c++) {
      const x = p[i + c];
      if (x < lo[c]) lo[c] = x;
      if (x > hi[c]) hi[c] = x;
    }
  }
  if (p.length === 0) return { center: [0, 0, 0], radius: 0 };
  const center: [number, number, number] = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2];
  let r2 = 0;
  for (let i = 0; i < p.length; i += 3) {
    const d = (p[i] - center[0]) ** 2 + (p[i + 1] - center[1]) ** 2 + (p[i + 2] - center[2]) ** 2;
    if (d > r2) r2 = d;
  }
  return { center, radius: Math.sqrt(r2) };
}
