// Pick and drag (issue 44): a click on the mesh makes a handle group of the surface around the
// point (the vertices connected to it through edges within a radius of it, like a soft brush
// that follows the surface, not a ball that jumps across gaps), and when nothing holds that part
// of the mesh yet, a fixed group on its far side; other parts that nothing holds are fixed whole,
// so that only the picked part moves. Pure: indices, positions and the groups in, vertex lists out.

/** Vertex adjacency in compressed rows: the neighbours of v are neighbors[offsets[v]..offsets[v+1]). */
export interface Adjacency {
  offsets: Uint32Array;
  neighbors: Uint32Array;
}

export function buildAdjacency(indices: ArrayLike<number>, vertexCount: number): Adjacency {
  const degree = new Uint32Array(vertexCount + 1);
  for (let f = 0; f + 2 < indices.length; f += 3) {
    for (let c = 0; c < 3; c++) {
      degree[indices[f + c]] += 2;
    }
  }
  const offsets = new Uint32Array(vertexCount + 1);
  for (let v = 0; v < vertexCount; v++) offsets[v + 1] = offsets[v] + degree[v];
  const fill = offsets.slice(0, vertexCount);
  const neighbors = new Uint32Array(offsets[vertexCount]);
  for (let f = 0; f + 2 < indices.length; f += 3) {
    for (let c = 0; c < 3; c++) {
      const v = indices[f + c];
      neighbors[fill[v]++] = indices[f + ((c + 1) % 3)];
      neighbors[fill[v]++] = indices[f + ((c + 2) % 3)];
    }
  }
  return { offsets, neighbors };
}

/** Connected component of every vertex (through edges); isolated vertices get their own. */
export function components(adj: Adjacency, vertexCount: number): { id: Int32Array; count: number } {
  const id = new Int32Array(vertexCount).fill(-1);
  const stack: number[] = [];
  let count = 0;
  for (let s = 0; s < vertexCount; s++) {
    if (id[s] >= 0) continue;
    id[s] = count;
    stack.push(s);
    while (stack.length) {
      const v = stack.pop()!;
      for (let k = adj.offsets[v]; k < adj.offsets[v + 1]; k++) {
        const w = adj.neighbors[k];
        if (id[w] < 0) { id[w] = count; stack.push(w); }
      }
    }
    count++;
  }
  return { id, count };
}

const dist2 = (p: ArrayLike<number>, v: number, c: readonly number[]) =>
  (p[v * 3] - c[0]) ** 2 + (p[v * 3 + 1] - c[1]) ** 2 + (p[v * 3 + 2] - c[2]) ** 2;

/** The vertices reachable from `seeds` through edges without leaving the ball of `radius` about
 * `center` (the seeds are taken whatever their distance), ascending. */
export function growRegion(p: ArrayLike<number>, adj: Adjacency, seeds: number[], center: readonly number[], radius: number): number[] {
  const r2 = radius * radius;
  const seen = new Set<number>(seeds);
  const stack = [...seeds];
  while (stack.length) {
    const v = stack.pop()!;
    for (let k = adj.offsets[v]; k < adj.offsets[v + 1]; k++) {
      const w = adj.neighbors[k];
      if (!seen.has(w) && dist2(p, w, center) <= r2) { seen.add(w); stack.push(w); }
    }
  }
  return [...seen].sort((a, b) => a - b);
}

/** The far side of component `comp` seen from `center`: its vertices at least `fraction` of the
 * farthest one's distance away (at least `min` of the farthest), excluding `taken`. Ascending. */
export function farSide(p: ArrayLike<number>, compId: Int32Array, comp: number, center: readonly number[],
  taken: (v: number) => boolean, fraction = 0.8, min = 3): number[] {
  const cand: { v: number; d: number }[] = [];
  let far = 0;
  for (let v = 0; v < compId.length; v++) {
    if (compId[v] !== comp || taken(v)) continue;
    const d = Math.sqrt(dist2(p, v, center));
    cand.push({ v, d });
    far = Math.max(far, d);
  }
  let out = cand.filter((c) => c.d >= fraction * far);
  if (out.length < min) out = [...cand].sort((a, b) => b.d - a.d).slice(0, min);
  return out.map((c) => c.v).sort((a, b) => a - b);
}

export interface PickInput {
  positions: ArrayLike<number>;
  adjacency: Adjacency;
  components: { id: Int32Array; count: number };
  /** The group of each vertex now (-1: free) and each group's role. */
  groupOf: (v: number) => number;
  roles: ("fixed" | "handle")[];
  /** The surface point clicked and the vertices of the face under it. */
  point: readonly number[];
  faceVertices: number[];
  radius: number;
}

export interface PickResult {
  /** The new handle group: the free vertices around the point. */
  handle: number[];
  /** A fixed group on the far side of the picked part, when nothing held that part. */
  farFixed: number[];
  /** Whole parts nothing held (fixed so that only the picked part moves). */
  otherParts: number[];
}

/** The groups a pick adds, or a sentence saying why it cannot. */
export function pickGroups(i: PickInput): PickResult | { reason: string } {
  const free = (v: number) => i.groupOf(v) < 0;
  const seeds = i.faceVertices.filter(free);
  if (seeds.length === 0) {
    return { reason: "That point is already in a group: drag a handle group (or delete the group to pick there)." };
  }
  const handle = growRegion(i.positions, i.adjacency, seeds, i.point, i.radius).filter(free);
  const comp = i.components.id[seeds[0]];
  // What holds each part now.
  const held = new Uint8Array(i.components.count);
  for (let v = 0; v < i.components.id.length; v++) if (!free(v)) held[i.components.id[v]] = 1;
  const inHandle = new Set(handle);
  const farFixed = held[comp] ? [] : farSide(i.positions, i.components.id, comp, i.point, (v) => !free(v) || inHandle.has(v));
  if (!held[comp] && farFixed.length === 0) {
    return { reason: "The radius covers the whole part: make it smaller (wheel or the Grab radius slider) so that something can stay fixed." };
  }
  const otherParts: number[] = [];
  for (let v = 0; v < i.components.id.length; v++) {
    const c = i.components.id[v];
    if (c !== comp && !held[c] && free(v)) otherParts.push(v);
  }
  return { handle, farFixed, otherParts };
}
