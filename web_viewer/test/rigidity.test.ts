import { describe, expect, it } from "vitest";
import { RIGIDITY_STEPS, rigidityLabel, rigidityStep, rigidityValue } from "../src/rigidity";

describe("rigidity slider", () => {
  it("maps every step to its value and back", () => {
    RIGIDITY_STEPS.forEach((v, i) => {
      expect(rigidityValue(i)).toBe(v);
      expect(rigidityStep(v)).toBe(i);
    });
  });
  it("snaps other values to the nearest step in log terms and clamps", () => {
    expect(rigidityStep(2.5)).toBe(RIGIDITY_STEPS.indexOf(3));
    expect(rigidityStep(0.05)).toBe(RIGIDITY_STEPS.indexOf(0.1));
    expect(rigidityStep(-1)).toBe(0);
    expect(rigidityStep(Number.NaN)).toBe(0);
    expect(rigidityStep(1e9)).toBe(RIGIDITY_STEPS.length - 1);
    expect(rigidityValue(-3)).toBe(0);
    expect(rigidityValue(99)).toBe(RIGIDITY_STEPS[RIGIDITY_STEPS.length - 1]);
  });
  it("labels the pure method", () => {
    expect(rigidityLabel(0)).toContain("paper");
    expect(rigidityLabel(3)).toBe("3");
  });
});
