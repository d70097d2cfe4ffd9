import { describe, expect, it } from "vitest";
import { autoScale, DEFAULT_HEAT_SCALE, heatMax, legend, parseScale, withScale } from "../src/heatscale";

describe("heat map scale", () => {
  it("is fixed per metric in the map's units", () => {
    expect(heatMax("angle", { angleDeg: 180, areaRatio: 2 })).toBeCloseTo(Math.PI);
    expect(heatMax("area", { angleDeg: 5, areaRatio: Math.E })).toBeCloseTo(1);
  });
  it("refuses scales that mean nothing", () => {
    expect(parseScale("angle", "0").ok).toBe(false);
    expect(parseScale("angle", "abc").ok).toBe(false);
    expect(parseScale("area", "1").ok).toBe(false);
    expect(parseScale("area", "1.5")).toEqual({ ok: true, value: 1.5 });
    expect(parseScale("angle", " 2.5 ")).toEqual({ ok: true, value: 2.5 });
  });
  it("Auto covers 98% of the values, rounded up to two digits", () => {
    const v = new Float32Array(100).map((_, i) => ((i + 1) / 100) * (Math.PI / 180) * 3); // 0.03..3 degrees
    expect(autoScale("angle", v)).toBeCloseTo(3, 5);
    const a = new Float32Array(100).fill(Math.log(1.234));
    expect(autoScale("area", a)).toBeCloseTo(1.24, 9);
  });
  it("the legend marks the top as 'or more' and does not depend on the data", () => {
    expect(legend("angle", DEFAULT_HEAT_SCALE).ticks).toEqual(["0°", "2.5°", "≥ 5.0°"]);
    expect(legend("area", withScale(DEFAULT_HEAT_SCALE, "area", 4)).ticks).toEqual(["×1", "×2.00", "≥ ×4.00 or ÷4.00"]);
  });
});
