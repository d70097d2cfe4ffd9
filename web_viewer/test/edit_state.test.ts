import { create } from "@bufbuild/protobuf";
import { describe, expect, it } from "vitest";
import { historyFromEdit, newGesture, settingsView, statesFromStep } from "../src/edit_state";
import {
  EditSettingsSchema, EditStateSchema, EditStepSchema, GroupMoveSchema, MagnifyRegionSchema, Method, QuaternionSchema, Vec3Schema,
} from "../src/gen/meshdeform/v1/deformation_pb";
import { applyMove, IDENTITY, type Vec3 } from "../src/moves";

const v = (x: number, y: number, z: number) => create(Vec3Schema, { x, y, z });

describe("settingsView", () => {
  it("gives the defaults before the first move", () => {
    expect(settingsView(undefined)).toEqual({ method: Method.SCALE_AWARE, ora: false, iterations: 2, rigidity: null, magnifyScale: 1, magnifyVertices: [] });
  });
  it("restores every setting of the last move", () => {
    const s = create(EditSettingsSchema, {
      method: Method.ARAP, ora: true, maxIterations: 12, rigidity: 30, tolerance: 1e-5,
      magnify: [create(MagnifyRegionSchema, { vertices: [5, 3], scale: 1.2 }), create(MagnifyRegionSchema, { vertices: [3, 9], scale: 1.7 })],
    });
    expect(settingsView(s)).toEqual({ method: Method.ARAP, ora: true, iterations: 12, rigidity: 30, magnifyScale: 1.7, magnifyVertices: [3, 5, 9] });
  });
});

describe("statesFromStep", () => {
  it("gives identity for groups without a move and keeps moves about the centroid", () => {
    const step = create(EditStepSchema, {
      moves: [create(GroupMoveSchema, { group: 1, translation: v(1, 2, 3), rotation: create(QuaternionSchema, { w: 2, x: 0, y: 0, z: 0 }), scale: 1.5, pivot: v(0, 0, 0) })],
    });
    const states = statesFromStep(step, [null, [0, 0, 0]]);
    expect(states[0]).toEqual(IDENTITY);
    expect(states[1]).toEqual({ translation: [1, 2, 3], rotation: [1, 0, 0, 0], scale: 1.5 });
  });
  it("re-expresses a move about another pivot with the same targets", () => {
    const h = Math.SQRT1_2;
    const pivot: Vec3 = [2, -1, 0.5];
    const centroid: Vec3 = [0.3, 0.4, -0.2];
    const step = create(EditStepSchema, {
      moves: [create(GroupMoveSchema, { group: 0, translation: v(0.1, 0.2, 0.3), rotation: create(QuaternionSchema, { w: h, x: 0, y: h, z: 0 }), scale: 0.8, pivot: v(...pivot) })],
    });
    const [state] = statesFromStep(step, [centroid]);
    const server = { translation: [0.1, 0.2, 0.3] as Vec3, rotation: [h, 0, h, 0] as [number, number, number, number], scale: 0.8 };
    for (const a of [[1, 0, 0], [0, 2, -1], [0.3, 0.4, -0.2]] as Vec3[]) {
      const want = applyMove(server, pivot, a);
      const got = applyMove(state, centroid, a);
      for (let k = 0; k < 3; k++) expect(got[k]).toBeCloseTo(want[k], 12);
    }
  });
});

describe("historyFromEdit", () => {
  it("maps steps to states and keeps the position", () => {
    const edit = create(EditStateSchema, {
      steps: [create(EditStepSchema, {}), create(EditStepSchema, { moves: [create(GroupMoveSchema, { group: 0, translation: v(1, 0, 0), scale: 1 })] })],
      position: 1,
    });
    const h = historyFromEdit(edit, [[0, 0, 0]]);
    expect(h.index).toBe(1);
    expect(h.states[0][0]).toEqual(IDENTITY);
    expect(h.states[1][0].translation).toEqual([1, 0, 0]);
    expect(historyFromEdit(undefined, [null]).states).toHaveLength(1);
  });
});

describe("newGesture", () => {
  it("is never zero", () => {
    expect(newGesture(() => 0)).toBe(1n);
    expect(newGesture(() => 0.999999) > 0n).toBe(true);
  });
});
