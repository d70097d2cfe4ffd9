import { describe, expect, it } from "vitest";
import { buildAdjacency, components, farSide, growRegion, pickGroups } from "../src/pick";

/** A strip of n x 2 vertices along x (two rows), triangulated; optionally a second strip far away. */
function strip(n: number, second = false) {
  const p: number[] = [];
  const idx: number[] = [];
  const add = (x0: number) => {
    const base = p.length / 3;
    for (let i = 0; i < n; i++) p.push(x0 + i, 0, 0, x0 + i, 1, 0);
    for (let i = 0; i + 1 < n; i++) {
      const a = base + 2 * i, b = a + 1, c = a + 2, d = a + 3;
      idx.push(a, c, b, b, c, d);
    }
  };
  add(0);
  if (second) add(100);
  return { p: Float32Array.from(p), idx: Uint32Array.from(idx), n: p.length / 3 };
}

describe("pick and drag groups", () => {
  it("adjacency and components", () => {
    const m = strip(4, true);
    const adj = buildAdjacency(m.idx, m.n);
    const c = components(adj, m.n);
    expect(c.count).toBe(2);
    expect(c.id[0]).toBe(c.id[7]);
    expect(c.id[0]).not.toBe(c.id[8]);
  });
  it("grows the region through edges within the radius", () => {
    const m = strip(10);
    const adj = buildAdjacency(m.idx, m.n);
    expect(growRegion(m.p, adj, [0], [0, 0, 0], 1.05)).toEqual([0, 1, 2]);
  });
  it("the far side is the part's vertices farthest from the point", () => {
    const m = strip(11);
    const c = components(buildAdjacency(m.idx, m.n), m.n);
    const far = farSide(m.p, c.id, 0, [0, 0, 0], () => false, 0.9);
    expect(far.every((v) => m.p[v * 3] >= 9)).toBe(true);
    expect(far.length).toBeGreaterThanOrEqual(2);
  });
  it("a pick on a mesh with no groups makes a handle, the far side fixed and the other part fixed whole", () => {
    const m = strip(11, true);
    const adj = buildAdjacency(m.idx, m.n);
    const r = pickGroups({
      positions: m.p, adjacency: adj, components: components(adj, m.n), groupOf: () => -1, roles: [],
      point: [0, 0, 0], faceVertices: [0, 2, 1], radius: 1.05,
    });
    if ("reason" in r) throw new Error(r.reason);
    expect(r.handle).toEqual([0, 1, 2]);
    expect(r.farFixed.every((v) => m.p[v * 3] >= 8 && m.p[v * 3] <= 10)).toBe(true);
    expect(r.otherParts.length).toBe(22);
    expect(r.otherParts.every((v) => m.p[v * 3] >= 100)).toBe(true);
  });
  it("no far side when something already holds the part, and vertices in groups are left alone", () => {
    const m = strip(11);
    const adj = buildAdjacency(m.idx, m.n);
    const groupOf = (v: number) => (m.p[v * 3] >= 9 ? 0 : v === 1 ? 1 : -1);
    const r = pickGroups({
      positions: m.p, adjacency: adj, components: components(adj, m.n), groupOf, roles: ["fixed", "handle"],
      point: [0, 0, 0], faceVertices: [0, 2, 1], radius: 1.05,
    });
    if ("reason" in r) throw new Error(r.reason);
    expect(r.handle).toEqual([0, 2]);
    expect(r.farFixed).toEqual([]);
    expect(r.otherParts).toEqual([]);
  });
  it("says why when the point is in a group already", () => {
    const m = strip(4);
    const adj = buildAdjacency(m.idx, m.n);
    const r = pickGroups({
      positions: m.p, adjacency: adj, components: components(adj, m.n), groupOf: () => 0, roles: ["handle"],
      point: [0, 0, 0], faceVertices: [0, 2, 1], radius: 1,
    });
    expect("reason" in r && r.reason).toMatch(/already in a group/);
  });
});
