// Vertex selection: brush (world-space sphere around the ray hit) and lasso (screen polygon).

/** Vertices within `radius` (world units) of `center`. */
export function brushSelect(positions: ArrayLike<number>, center: [number, number, number], radius: number): number[] {
  const out: number[] = [];
  const r2 = radius * radius;
  const n = positions.length / 3;
  for (let i = 0; i < n; i++) {
    const dx = positions[i * 3] - center[0];
    const dy = positions[i * 3 + 1] - center[1];
    const dz = positions[i * 3 + 2] - center[2];
    if (dx * dx + dy * dy + dz * dz <= r2) out.push(i);
  }
  return out;
}

/** Even-odd point-in-polygon test; `poly` is flat [x0, y0, x1, y1, ...]. */
export function pointInPolygon(x: number, y: number, poly: ArrayLike<number>): boolean {
  const n = poly.length / 2;
  if (n < 3) return false;
  let inside = false;
  for (let i = 0, j = n - 1; i < n; j = i++) {
    const xi = poly[i * 2], yi = poly[i * 2 + 1];
    const xj = poly[j * 2], yj = poly[j * 2 + 1];
    if (yi > y !== yj > y && x < ((xj - xi) * (y - yi)) / (yj - yi) + xi) inside = !inside;
  }
  return inside;
}

/**
 * Vertices whose screen projection lies inside `poly` and that face the camera.
 * `project(i)` returns the vertex's screen [x, y] or null if behind the camera; `facing(i)` says
 * whether its normal points towards the camera (occlusion by other parts is not tested).
 */
export function lassoSelect(
  count: number,
  poly: ArrayLike<number>,
  project: (i: number) => [number, number] | null,
  facing: (i: number) => boolean,
): number[] {
  let minX = Infinity, minY = Infinity, maxX = -Infinity, maxY = -Infinity;
  for (let i = 0; i < poly.length; i += 2) {
    minX = Math.min(minX, poly[i]); maxX = Math.max(maxX, poly[i]);
    minY = Math.min(minY, poly[i + 1]); maxY = Math.max(maxY, poly[i + 1]);
  }
  const out: number[] = [];
  for (let i = 0; i < count; i++) {
    const p = project(i);
    if (!p) continue;
    const [x, y] = p;
    if (x < minX || x > maxX || y < minY || y > maxY) continue;
    if (pointInPolygon(x, y, poly) && facing(i)) out.push(i);
  }
  return out;
}

export type PaintMode = "fixed" | "handle" | "magnify" | "erase";

/** The magnify region: a per-vertex flag, independent of the handle groups (src/groups.ts). */
export class SelectionState {
  magnify: Uint8Array;

  constructor(readonly vertexCount: number) {
    this.magnify = new Uint8Array(vertexCount);
  }

  /** Mode "magnify" adds to the region, "erase" removes from it; other modes do not touch it. */
  paint(indices: Iterable<number>, mode: PaintMode): void {
    if (mode !== "magnify" && mode !== "erase") return;
    for (const i of indices) this.magnify[i] = mode === "magnify" ? 1 : 0;
  }

  clear(): void {
    this.magnify.fill(0);
  }

  magnifyIndices(): number[] {
    const out: number[] = [];
    for (let i = 0; i < this.vertexCount; i++) if (this.magnify[i]) out.push(i);
    return out;
  }

  get hasMagnify(): boolean {
    return this.magnify.includes(1);
  }
}
