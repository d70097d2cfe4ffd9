import { describe, expect, it } from "vitest";
import { brushSelect, lassoSelect, pointInPolygon, SelectionState } from "../src/selection";

describe("lasso", () => {
  const square = [0, 0, 10, 0, 10, 10, 0, 10];
  const concave = [0, 0, 10, 0, 10, 10, 5, 3, 0, 10]; // a "V" notch from the top
  it("point in polygon (convex and concave)", () => {
    expect(pointInPolygon(5, 5, square)).toBe(true);
    expect(pointInPolygon(11, 5, square)).toBe(false);
    expect(pointInPolygon(-0.1, 5, square)).toBe(false);
    expect(pointInPolygon(5, 1, concave)).toBe(true);
    expect(pointInPolygon(5, 8, concave)).toBe(false);
    expect(pointInPolygon(1, 1, [0, 0, 1, 1])).toBe(false); // degenerate
  });
  it("selects projected vertices inside that face the camera", () => {
    const screen: [number, number][] = [[5, 5], [20, 5], [2, 2], [3, 3]];
    const facing = [true, true, true, false];
    const got = lassoSelect(4, square, (i) => screen[i], (i) => facing[i]);
    expect(got).toEqual([0, 2]);
    expect(lassoSelect(2, square, () => null, () => true)).toEqual([]);
  });
});

describe("brush", () => {
  it("selects vertices within the world-space radius", () => {
    const p = [0, 0, 0, 1, 0, 0, 0, 2, 0, 0.5, 0.5, 0.5];
    expect(brushSelect(p, [0, 0, 0], 1)).toEqual([0, 1, 3]);
    expect(brushSelect(p, [0, 0, 0], 0.5)).toEqual([0]);
    expect(brushSelect(p, [0, 2, 0], 0.1)).toEqual([2]);
  });
});

describe("SelectionState", () => {
  it("paints roles, magnify and erase; validates", () => {
    const s = new SelectionState(6);
    expect(s.validate()).toMatch(/empty/);
    s.paint([0, 1], "fixed");
    expect(s.validate()).toMatch(/handle/);
    s.paint([4, 5], "handle");
    s.paint([2, 3, 4], "magnify");
    expect(s.validate()).toBeNull();
    expect(s.indicesWithRole(1)).toEqual([0, 1]);
    expect(s.indicesWithRole(2)).toEqual([4, 5]);
    expect(s.magnifyIndices()).toEqual([2, 3, 4]);
    s.paint([1, 4], "erase");
    expect(s.indicesWithRole(1)).toEqual([0]);
    expect(s.magnifyIndices()).toEqual([2, 3]);
    s.paint([5], "fixed"); // repainting moves a vertex between groups: no vertex in two groups
    expect(s.indicesWithRole(2)).toEqual([]);
  });
});
