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
  it("paints and erases the magnify region only", () => {
    const s = new SelectionState(6);
    expect(s.hasMagnify).toBe(false);
    s.paint([0, 1], "fixed"); // roles live in GroupSet
    expect(s.magnifyIndices()).toEqual([]);
    s.paint([2, 3, 4], "magnify");
    expect(s.magnifyIndices()).toEqual([2, 3, 4]);
    expect(s.hasMagnify).toBe(true);
    s.paint([3, 5], "erase");
    expect(s.magnifyIndices()).toEqual([2, 4]);
    s.clear();
    expect(s.hasMagnify).toBe(false);
  });
});
