import { describe, expect, it } from "vitest";
import { modalState, screenAngle, screenScale, type ModalPointer } from "../src/modal";
import { applyMove, IDENTITY, type Vec3 } from "../src/moves";

const pointer = (over: Partial<ModalPointer> = {}): ModalPointer => ({
  centre: [100, 100], start: [150, 100], now: [150, 100], planeDelta: [0, 0, 0], towardViewer: [0, 0, 1], ...over,
});
const close = (a: number[], b: number[], tol = 1e-9) => a.every((x, i) => Math.abs(x - b[i]) <= tol);

describe("modal transforms from the pointer", () => {
  it("a free move follows the pointer's travel on the view plane", () => {
    const r = modalState(IDENTITY, "translate", null, null, pointer({ planeDelta: [0.1, -0.2, 0.05] }));
    expect(r.state.translation).toEqual([0.1, -0.2, 0.05]);
  });
  it("an axis lock keeps the travel's component along the axis only", () => {
    const r = modalState(IDENTITY, "translate", "y", null, pointer({ planeDelta: [0.1, -0.2, 0.05] }));
    expect(close(r.state.translation, [0, -0.2, 0])).toBe(true);
  });
  it("a typed amount replaces the pointer's", () => {
    const r = modalState(IDENTITY, "translate", "z", 2, pointer({ planeDelta: [5, 5, 5] }));
    expect(r.state.translation).toEqual([0, 0, 2]);
  });
  it("rotation follows the pointer's angle about the group's centre on screen, counter-clockwise positive", () => {
    // From the right of the centre to above it (screen y down): a quarter turn counter-clockwise.
    expect(screenAngle([100, 100], [150, 100], [100, 50])).toBeCloseTo(90);
    const r = modalState(IDENTITY, "rotate", null, null, pointer({ now: [100, 50] }));
    // About the view axis (towards the viewer, +z): x goes to y.
    expect(close(applyMove(r.state, [0, 0, 0], [1, 0, 0]), [0, 1, 0], 1e-9)).toBe(true);
  });
  it("a locked axis pointing away from the viewer turns the other way, so the turn still follows the pointer", () => {
    const toward = modalState(IDENTITY, "rotate", "z", null, pointer({ now: [100, 50], towardViewer: [0, 0, 1] }));
    const away = modalState(IDENTITY, "rotate", "z", null, pointer({ now: [100, 50], towardViewer: [0, 0, -1] }));
    const p: Vec3 = [1, 0, 0];
    expect(close(applyMove(toward.state, [0, 0, 0], p), [0, 1, 0])).toBe(true);
    expect(close(applyMove(away.state, [0, 0, 0], p), [0, -1, 0])).toBe(true);
  });
  it("scale is the pointer's distance from the centre over its distance at the start", () => {
    expect(screenScale([100, 100], [150, 100], [200, 100])).toBe(2);
    expect(screenScale([100, 100], [100, 100], [100, 100])).toBe(1); // no division by zero
    expect(modalState(IDENTITY, "scale", null, null, pointer({ now: [125, 100] })).state.scale).toBe(0.5);
    expect(modalState(IDENTITY, "scale", null, 3, pointer()).state.scale).toBe(3);
  });
  it("composes with the state the command started from", () => {
    const base = { ...IDENTITY, translation: [1, 2, 3] as Vec3, scale: 2 };
    const r = modalState(base, "translate", "x", 0.5, pointer());
    expect(r.state.translation).toEqual([1.5, 2, 3]);
    expect(r.state.scale).toBe(2);
  });
});
