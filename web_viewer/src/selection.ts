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

/** Per-vertex selection: role 0 none, 1 fixed, 2 handle; magnify is an independent flag. */
export class SelectionState {
  role: Uint8Array;
  magnify: Uint8Array;

  constructor(readonly vertexCount: number) {
    this.role = new Uint8Array(vertexCount);
    this.magnify = new Uint8Array(vertexCount);
  }

  paint(indices: Iterable<number>, mode: PaintMode): void {
    for (const i of indices) {
      if (mode === "fixed") this.role[i] = 1;
      else if (mode === "handle") this.role[i] = 2;
      else if (mode === "magnify") this.magnify[i] = 1;
      else { this.role[i] = 0; this.magnify[i] = 0; }
    }
  }

  clear(): void {
    this.role.fill(0);
    this.magnify.fill(0);
  }

  indicesWithRole(role: number): number[] {
    const out: number[] = [];
    for (let i = 0; i < this.vertexCount; i++) if (this.role[i] === role) out.push(i);
    return out;
  }

  magnifyIndices(): number[] {
    const out: number[] = [];
    for (let i = 0; i < this.vertexCount; i++) if (this.magnify[i]) out.push(i);
    return out;
  }

  /** null when the selection can become handles, else a message for the user. */
  validate(): string | null {
    const f = this.indicesWithRole(1).length;
    const h = this.indicesWithRole(2).length;
    if (f === 0 && h === 0) return "Selection is empty: paint a fixed region and a handle, then Apply.";
    if (f === 0) return "No fixed region: paint one in mode \u201cfixed\u201d.";
    if (h === 0) return "No handle: paint one in mode \u201chandle\u201d.";
    return null;
  }
}
