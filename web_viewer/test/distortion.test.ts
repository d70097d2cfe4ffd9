import { describe, expect, it } from "vitest";
import { cornerAngles, faceAreas2, ramp, scaleMax, vertexAreaLog, vertexDistortion } from "../src/distortion";

// A small open grid mesh (3x3 vertices, 8 triangles).
function grid(): { p: Float32Array; f: Uint32Array } {
  const p: number[] = [];
  for (let j = 0; j < 3; j++) for (let i = 0; i < 3; i++) p.push(i, j, 0.1 * i * j);
  const f: number[] = [];
  for (let j = 0; j < 2; j++)
    for (let i = 0; i < 2; i++) {
      const a = j * 3 + i;
      f.push(a, a + 1, a + 4, a, a + 4, a + 3);
    }
  return { p: new Float32Array(p), f: new Uint32Array(f) };
}

describe("distortion heat map", () => {
  it("sums to pi per triangle", () => {
    const { p, f } = grid();
    const a = cornerAngles(p, f);
    for (let t = 0; t < f.length / 3; t++) expect(a[t * 3] + a[t * 3 + 1] + a[t * 3 + 2]).toBeCloseTo(Math.PI, 5);
  });
  it("is zero on the rest mesh and on a rotated, scaled, translated copy", () => {
    const { p, f } = grid();
    const rest = cornerAngles(p, f);
    expect(Math.max(...vertexDistortion(rest, p, f, 9))).toBe(0);
    const q = new Float32Array(p.length);
    const c = Math.cos(0.7), s = Math.sin(0.7);
    for (let i = 0; i < 9; i++) {
      const [x, y, z] = [p[i * 3], p[i * 3 + 1], p[i * 3 + 2]];
      q[i * 3] = 2.5 * (c * x - s * y) + 3;
      q[i * 3 + 1] = 2.5 * (s * x + c * y) - 1;
      q[i * 3 + 2] = 2.5 * z + 7;
    }
    expect(Math.max(...vertexDistortion(rest, q, f, 9))).toBeLessThan(1e-5);
  });
  it("is positive after a non-similar change, largest near it", () => {
    const { p, f } = grid();
    const rest = cornerAngles(p, f);
    const q = Float32Array.from(p);
    q[8 * 3] += 0.8; // pull a corner vertex sideways
    const d = vertexDistortion(rest, q, f, 9);
    expect(d[8]).toBeGreaterThan(0.01);
    expect(d[0]).toBe(0); // far corner shares no face with vertex 8
    // Non-uniform scale is not a similarity either.
    const r = Float32Array.from(p);
    for (let i = 0; i < 9; i++) r[i * 3] *= 2;
    expect(Math.max(...vertexDistortion(rest, r, f, 9))).toBeGreaterThan(0.05);
  });
  it("ramps from dark to bright and clamps", () => {
    const lo = ramp(0), hi = ramp(1);
    expect(lo[0] + lo[1] + lo[2]).toBeLessThan(hi[0] + hi[1] + hi[2]);
    expect(ramp(-5)).toEqual(lo);
    expect(ramp(NaN)).toEqual(lo);
    expect(scaleMax(new Float32Array([0, 0, 0]))).toBe(1e-3);
  });
});

describe("area heat map", () => {
  const transform = (p: Float32Array, scale: number): Float32Array => {
    const q = new Float32Array(p.length);
    const c = Math.cos(0.7), s = Math.sin(0.7);
    for (let i = 0; i < p.length / 3; i++) {
      const [x, y, z] = [p[i * 3], p[i * 3 + 1], p[i * 3 + 2]];
      q[i * 3] = scale * (c * x - s * y) + 1;
      q[i * 3 + 1] = scale * (s * x + c * y) - 2;
      q[i * 3 + 2] = scale * z + 0.5;
    }
    return q;
  };
  it("is zero under a rigid motion and 2 log s under a uniform scale s", () => {
    const { p, f } = grid();
    const rest = faceAreas2(p, f);
    for (const v of vertexAreaLog(rest, transform(p, 1), f, 9)) expect(Math.abs(v)).toBeLessThan(1e-5);
    for (const v of vertexAreaLog(rest, transform(p, 1.5), f, 9)) expect(v).toBeCloseTo(2 * Math.log(1.5), 4);
  });
  it("is positive where faces grew and negative where they shrank", () => {
    const { p, f } = grid();
    const rest = faceAreas2(p, f);
    const q = Float32Array.from(p);
    q[8 * 3] += 1; q[8 * 3 + 1] += 1;  // pull the corner vertex 8 outward: its faces grow
    const d = vertexAreaLog(rest, q, f, 9);
    expect(d[8]).toBeGreaterThan(0.1);
    expect(d[0]).toBe(0);  // far corner untouched
    const r = Float32Array.from(p);
    r[8 * 3] -= 0.5; r[8 * 3 + 1] -= 0.5;  // push it inward: they shrink
    expect(vertexAreaLog(rest, r, f, 9)[8]).toBeLessThan(-0.1);
  });
});
