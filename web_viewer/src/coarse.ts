// The coarse level of a multiresolution drag (issue 44): the Watch stream (coarse_preview) adds
// to each update of a move solved on a coarse level that level's positions, and its triangles
// and to_fine the first time the stream sends its key. The worker keeps them here and hands the
// page a coarse frame beside the full one; during a drag the page draws the coarse mesh (a
// fraction of the vertices to upload and draw), after the release the full one.
import type { CoarseLevel } from "./gen/meshdeform/v1/deformation_pb";
import { vertexNormals } from "./geometry";

/** What the page draws of the coarse level. The mesh travels with the first frame of its key. */
export interface CoarseFrame {
  key: string;
  positions: Float32Array;
  normals: Float32Array;
  mesh: { indices: Uint32Array; toFine: Uint32Array } | null;
}

/** The newest update's coarse level (null when that update had none), checked against the
 * full mesh it belongs to. */
export class CoarseLevelState {
  private mesh: { key: string; indices: Uint32Array; toFine: Uint32Array } | null = null;
  private positions: Float32Array | null = null;
  private sentKey = "";

  constructor(private readonly vertexCount: number) {}

  /** Takes an update's coarse level (undefined: the update had none, e.g. a refinement).
   * @throws Error for a level that does not fit (its mesh unknown, sizes, indices). */
  apply(c: CoarseLevel | undefined): void {
    if (!c) {
      this.positions = null;
      return;
    }
    const key = c.key.toString();
    const n = c.vertexCount;
    if (c.toFine.length > 0 || c.triangles.length > 0) {
      if (c.toFine.length !== n) throw new Error(`coarse level ${key}: ${c.toFine.length} to_fine entries for ${n} vertices`);
      if (c.triangles.length % 3 !== 0 || c.triangles.length === 0) throw new Error(`coarse level ${key}: ${c.triangles.length} triangle indices`);
      for (const t of c.triangles) if (t >= n) throw new Error(`coarse level ${key}: triangle index ${t} of ${n} vertices`);
      for (const v of c.toFine) if (v >= this.vertexCount) throw new Error(`coarse level ${key}: vertex ${v} of ${this.vertexCount}`);
      this.mesh = { key, indices: Uint32Array.from(c.triangles), toFine: Uint32Array.from(c.toFine) };
    }
    if (!this.mesh || this.mesh.key !== key) throw new Error(`coarse level ${key} came without its mesh`);
    if (this.mesh.toFine.length !== n || c.positions.length !== 12 * n) {
      throw new Error(`coarse level ${key}: ${c.positions.length} position bytes for ${n} vertices`);
    }
    // A copy: the update's bytes need not be aligned for a Float32Array view.
    const p = new Float32Array(3 * n);
    new Uint8Array(p.buffer).set(c.positions);
    this.positions = p;
  }

  /** Whether the newest update had a coarse level. */
  get present(): boolean {
    return this.positions !== null;
  }

  /** The frame for the page (with the mesh when the page has not had this key), or null. */
  frame(): CoarseFrame | null {
    const m = this.mesh, p = this.positions;
    if (!m || !p) return null;
    const first = this.sentKey !== m.key;
    this.sentKey = m.key;
    // Copies: the frame's buffers are transferred to the page.
    return {
      key: m.key, positions: p.slice(), normals: vertexNormals(p, m.indices, new Float32Array(p.length)),
      mesh: first ? { indices: m.indices.slice(), toFine: m.toFine.slice() } : null,
    };
  }
}
