// Client-side distortion heat map: per vertex, the mean absolute change of the corner angles of
// the faces around it against the rest mesh. Invariant to rotation, translation and uniform
// scale, so it highlights non-similar deformation only.

/** The three corner angles of every face (radians), flat [f0c0, f0c1, f0c2, ...]. */
export function cornerAngles(p: ArrayLike<number>, indices: ArrayLike<number>): Float32Array {
  const m = indices.length / 3;
  const out = new Float32Array(m * 3);
  for (let f = 0; f < m; f++) {
    for (let c = 0; c < 3; c++) {
      const a = indices[f * 3 + c] * 3;
      const b = indices[f * 3 + ((c + 1) % 3)] * 3;
      const d = indices[f * 3 + ((c + 2) % 3)] * 3;
      const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
      const vx = p[d] - p[a], vy = p[d + 1] - p[a + 1], vz = p[d + 2] - p[a + 2];
      // atan2(|u x v|, u.v) is accurate for tiny and near-flat angles, unlike acos.
      const cx = uy * vz - uz * vy, cy = uz * vx - ux * vz, cz = ux * vy - uy * vx;
      out[f * 3 + c] = Math.atan2(Math.hypot(cx, cy, cz), ux * vx + uy * vy + uz * vz);
    }
  }
  return out;
}

/** Per vertex, the mean of a per-face value over the faces around it (0 for a lone vertex). */
export function perVertexMean(faceValues: ArrayLike<number>, indices: ArrayLike<number>, vertexCount: number): Float32Array {
  const sum = new Float64Array(vertexCount);
  const cnt = new Uint32Array(vertexCount);
  for (let f = 0; f < faceValues.length; f++) {
    for (let c = 0; c < 3; c++) {
      const v = indices[f * 3 + c];
      sum[v] += faceValues[f];
      cnt[v]++;
    }
  }
  const out = new Float32Array(vertexCount);
  for (let v = 0; v < vertexCount; v++) out[v] = cnt[v] ? sum[v] / cnt[v] : 0;
  return out;
}

/** Per-vertex mean |angle - rest angle| over the corners of the incident faces. */
export function vertexDistortion(
  restAngles: Float32Array,
  p: ArrayLike<number>,
  indices: ArrayLike<number>,
  vertexCount: number,
): Float32Array {
  const cur = cornerAngles(p, indices);
  const perFace = new Float64Array(indices.length / 3);
  for (let f = 0; f < perFace.length; f++) {
    perFace[f] = (Math.abs(cur[f * 3] - restAngles[f * 3]) + Math.abs(cur[f * 3 + 1] - restAngles[f * 3 + 1]) +
      Math.abs(cur[f * 3 + 2] - restAngles[f * 3 + 2])) / 3;
  }
  return perVertexMean(perFace, indices, vertexCount);
}

/** Twice the area of every face (|cross|), flat [f0, f1, ...]. */
export function faceAreas2(p: ArrayLike<number>, indices: ArrayLike<number>): Float64Array {
  const m = indices.length / 3;
  const out = new Float64Array(m);
  for (let f = 0; f < m; f++) {
    const a = indices[f * 3] * 3, b = indices[f * 3 + 1] * 3, d = indices[f * 3 + 2] * 3;
    const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
    const vx = p[d] - p[a], vy = p[d + 1] - p[a + 1], vz = p[d + 2] - p[a + 2];
    out[f] = Math.hypot(uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx);
  }
  return out;
}

/**
 * Per-vertex area (scale) distortion: the mean of log(area / rest area) over the incident faces,
 * signed (positive: grown, negative: shrunk). Zero under rigid motion; a uniform scale s gives
 * 2 log s everywhere. The angle map hides scale drift by design; this shows it (issue 12).
 */
export function vertexAreaLog(
  restAreas2: Float64Array,
  p: ArrayLike<number>,
  indices: ArrayLike<number>,
  vertexCount: number,
): Float32Array {
  const cur = faceAreas2(p, indices);
  const perFace = new Float64Array(cur.length);
  for (let f = 0; f < cur.length; f++) {
    const rest = restAreas2[f];
    perFace[f] = rest > 0 && cur[f] > 0 ? Math.log(cur[f] / rest) : 0;
  }
  return perVertexMean(perFace, indices, vertexCount);
}

// Viridis control points (perceptually uniform, colour-blind friendly).
const VIRIDIS: [number, number, number][] = [
  [0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.53], [0.207, 0.372, 0.553],
  [0.164, 0.471, 0.558], [0.128, 0.567, 0.551], [0.135, 0.659, 0.518], [0.267, 0.749, 0.441],
  [0.478, 0.821, 0.318], [0.741, 0.873, 0.15], [0.993, 0.906, 0.144],
];

/** t in [0, 1] -> linear-ish RGB in [0, 1]. */
export function ramp(t: number): [number, number, number] {
  const x = Math.min(1, Math.max(0, Number.isFinite(t) ? t : 0)) * (VIRIDIS.length - 1);
  const i = Math.min(VIRIDIS.length - 2, Math.floor(x));
  const f = x - i;
  const a = VIRIDIS[i], b = VIRIDIS[i + 1];
  return [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];
}

export function rampCss(): string {
  return `linear-gradient(to right, ${VIRIDIS.map((c) => `rgb(${c.map((x) => Math.round(x * 255)).join(",")})`).join(", ")})`;
}

/** A robust colour scale maximum: the 98th percentile, at least a small floor. */
export function scaleMax(values: Float32Array, floor = 1e-3): number {
  if (values.length === 0) return floor;
  const s = Float32Array.from(values).sort();
  return Math.max(floor, s[Math.min(s.length - 1, Math.floor(s.length * 0.98))]);
}
