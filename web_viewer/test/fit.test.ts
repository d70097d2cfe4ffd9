import { describe, expect, it } from "vitest";
import { applyMove, axisAngle, fitSimilarity, type MoveState, type Vec3 } from "../src/moves";

function rows(points: Vec3[]): number[] {
  return points.flat();
}
function centroid(p: number[]): Vec3 {
  const n = p.length / 3;
  const c: Vec3 = [0, 0, 0];
  for (let i = 0; i < n; i++) for (let k = 0; k < 3; k++) c[k] += p[i * 3 + k] / n;
  return c;
}

describe("fitSimilarity", () => {
  const from = rows([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3], [1, 1, 1]]);
  it("recovers a similarity about the centroid of the points", () => {
    const truth: MoveState = { translation: [0.3, -1, 2], rotation: axisAngle([1, 2, 3], 70), scale: 1.7 };
    const c = centroid(from);
    const to: number[] = [];
    for (let i = 0; i < from.length; i += 3) to.push(...applyMove(truth, c, [from[i], from[i + 1], from[i + 2]]));
    const fit = fitSimilarity(from, to);
    expect(fit.scale).toBeCloseTo(1.7, 9);
    for (let i = 0; i < from.length; i += 3) {
      const p = applyMove(fit, c, [from[i], from[i + 1], from[i + 2]]);
      for (let k = 0; k < 3; k++) expect(p[k]).toBeCloseTo(to[i + k], 9);
    }
  });
  it("a single point: a translation", () => {
    expect(fitSimilarity([1, 2, 3], [2, 2, 2])).toEqual({ translation: [1, 0, -1], rotation: [1, 0, 0, 0], scale: 1 });
  });
  it("the identity for equal points", () => {
    const fit = fitSimilarity(from, from);
    expect(fit.scale).toBeCloseTo(1, 12);
    expect(Math.abs(fit.rotation[0])).toBeCloseTo(1, 12);
    for (const t of fit.translation) expect(t).toBeCloseTo(0, 12);
  });
});
