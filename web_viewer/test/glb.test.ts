import { describe, expect, it } from "vitest";
import { buildGlb, parseGlb } from "../src/glb";

describe("GLB parser", () => {
  it("round-trips positions and uint32 indices in order", () => {
    const positions = new Float32Array([0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1.5]);
    const indices = new Uint32Array([0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2]);
    const glb = buildGlb(positions, indices);
    expect(glb.byteLength % 4).toBe(0);
    const m = parseGlb(glb);
    expect(Array.from(m.positions)).toEqual(Array.from(positions));
    expect(Array.from(m.indices)).toEqual(Array.from(indices));
  });
  it("works on a GLB at a non-zero byte offset", () => {
    const glb = buildGlb(new Float32Array([1, 2, 3, 4, 5, 6, 7, 8, 9]), new Uint32Array([0, 1, 2]));
    const big = new Uint8Array(glb.length + 3);
    big.set(glb, 3);
    const m = parseGlb(big.subarray(3));
    expect(Array.from(m.positions)).toEqual([1, 2, 3, 4, 5, 6, 7, 8, 9]);
  });
  it("rejects non-GLB input and out-of-range indices", () => {
    expect(() => parseGlb(new TextEncoder().encode("v 0 0 0\nf 1 2 3\n"))).toThrow(/GLB/);
    const bad = buildGlb(new Float32Array([0, 0, 0, 1, 0, 0, 0, 1, 0]), new Uint32Array([0, 1, 5]));
    expect(() => parseGlb(bad)).toThrow(/range/);
  });
});
