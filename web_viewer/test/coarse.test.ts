import { create } from "@bufbuild/protobuf";
import { describe, expect, it } from "vitest";
import { CoarseLevelState } from "../src/coarse";
import { CoarseLevelSchema } from "../src/gen/meshdeform/v1/deformation_pb";

// A coarse level of two triangles on four of a ten-vertex mesh's vertices.
const toFine = [0, 3, 7, 9];
const triangles = [0, 1, 2, 0, 2, 3];
function bytes(xyz: number[]): Uint8Array {
  return new Uint8Array(Float32Array.from(xyz).buffer);
}
const flat = [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0];
const level = (withMesh: boolean, xyz = flat, key = 42n) =>
  create(CoarseLevelSchema, {
    key, vertexCount: 4, positions: bytes(xyz), triangles: withMesh ? triangles : [], toFine: withMesh ? toFine : [],
  });

describe("CoarseLevelState", () => {
  it("hands the page the mesh with the first frame of a key, then positions and normals only", () => {
    const s = new CoarseLevelState(10);
    expect(s.frame()).toBeNull();
    s.apply(level(true));
    const first = s.frame()!;
    expect(first.key).toBe("42");
    expect([...first.positions]).toEqual(flat);
    expect([...first.mesh!.indices]).toEqual(triangles);
    expect([...first.mesh!.toFine]).toEqual(toFine);
    // A flat square in z = 0, counter-clockwise: every normal is +z.
    for (let i = 0; i < 4; i++) expect([...first.normals.subarray(3 * i, 3 * i + 3)]).toEqual([0, 0, 1]);
    const moved = flat.map((v, i) => (i % 3 === 2 ? 2 : v));
    s.apply(level(false, moved));
    const second = s.frame()!;
    expect(second.mesh).toBeNull();
    expect([...second.positions]).toEqual(moved);
    // The frame's buffers are the page's (transferred): the state keeps its own.
    second.positions.fill(0);
    expect([...s.frame()!.positions]).toEqual(moved);
  });

  it("an update without a level (a refinement) ends the preview; the mesh stays known", () => {
    const s = new CoarseLevelState(10);
    s.apply(level(true));
    s.frame();
    s.apply(undefined);
    expect(s.present).toBe(false);
    expect(s.frame()).toBeNull();
    s.apply(level(false));
    expect(s.frame()?.mesh).toBeNull();
  });

  it("refuses a level that does not fit, naming it", () => {
    const s = new CoarseLevelState(10);
    expect(() => s.apply(level(false))).toThrow(/42 came without its mesh/);
    expect(() => s.apply(create(CoarseLevelSchema, { key: 1n, vertexCount: 4, positions: bytes(flat), triangles, toFine: [0, 3, 7, 10] })))
      .toThrow(/vertex 10 of 10/);
    expect(() => s.apply(create(CoarseLevelSchema, { key: 1n, vertexCount: 4, positions: bytes(flat), triangles: [0, 1, 4], toFine })))
      .toThrow(/triangle index 4/);
    expect(() => s.apply(level(true, flat.slice(0, 9)))).toThrow(/36 position bytes/);
    s.apply(level(true));
    expect(() => s.apply(level(false, flat, 43n))).toThrow(/43 came without its mesh/);
  });
});
