import { describe, expect, it } from "vitest";
import * as THREE from "three";
import { boundingSphere, vertexNormals } from "../src/geometry";

describe("geometry off the main thread", () => {
  it("normals and the bounding sphere match three.js's", () => {
    const g = new THREE.TorusKnotGeometry(1, 0.3, 32, 6);
    const p = g.getAttribute("position").array as Float32Array;
    const idx = g.getIndex()!.array as Uint32Array;
    g.computeVertexNormals();
    g.computeBoundingSphere();
    const mine = vertexNormals(p, idx, new Float32Array(p.length));
    const theirs = g.getAttribute("normal").array as Float32Array;
    for (let i = 0; i < p.length; i++) expect(mine[i]).toBeCloseTo(theirs[i], 5);
    const s = boundingSphere(p);
    expect(s.radius).toBeCloseTo(g.boundingSphere!.radius, 5);
    expect(s.center[0]).toBeCloseTo(g.boundingSphere!.center.x, 5);
  });
});
