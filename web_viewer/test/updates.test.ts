import { beforeAll, describe, expect, it } from "vitest";
import { create } from "@bufbuild/protobuf";
import { DeformResultSchema, DeformUpdateSchema, PositionEncoding, type DeformUpdate } from "../src/gen/meshdeform/v1/deformation_pb";
import { toBinary } from "@bufbuild/protobuf";
import { PositionState, decoderReady, parseEncoding, encodingName, updateWireBytes } from "../src/updates";

const N = 5;
const rest = Array.from({ length: N * 3 }, (_, i) => i * 0.5 - 1); // exactly representable in float32

function f32bytes(vals: number[]): Uint8Array {
  const b = new Uint8Array(vals.length * 4);
  const dv = new DataView(b.buffer);
  vals.forEach((v, i) => dv.setFloat32(i * 4, v, true));
  return b;
}

let encoder: { encodeVertexBuffer(src: Uint8Array, count: number, size: number): Uint8Array } | null = null;
let encoderSkipReason = "";
beforeAll(async () => {
  await decoderReady();
  try {
    const mod: any = await import("meshoptimizer/encoder");
    await mod.MeshoptEncoder.ready;
    encoder = mod.MeshoptEncoder;
  } catch (e) {
    encoderSkipReason = `MeshoptEncoder unavailable in Node: ${e}`;
  }
});

function pack(enc: PositionEncoding, vals: number[]): { doubles: number[]; packed: Uint8Array } {
  if (enc === PositionEncoding.UNSPECIFIED) return { doubles: vals, packed: new Uint8Array(0) };
  const f = f32bytes(vals);
  if (enc === PositionEncoding.FLOAT32) return { doubles: [], packed: f };
  return { doubles: [], packed: encoder!.encodeVertexBuffer(f, vals.length / 3, 12) };
}

function snapshot(enc: PositionEncoding, rev: number, vals: number[]): DeformUpdate {
  const p = pack(enc, vals);
  return create(DeformUpdateSchema, {
    isSnapshot: true,
    result: create(DeformResultSchema, { revision: BigInt(rev), encoding: enc, positions: p.doubles, packedPositions: p.packed }),
  });
}
function delta(enc: PositionEncoding, rev: number, idx: number[], vals: number[]): DeformUpdate {
  const p = pack(enc, vals);
  return create(DeformUpdateSchema, {
    result: create(DeformResultSchema, {
      revision: BigInt(rev), encoding: enc, changedIndices: idx, changedPositions: p.doubles, packedChangedPositions: p.packed,
    }),
  });
}

for (const [name, enc] of [["double", PositionEncoding.UNSPECIFIED], ["float32", PositionEncoding.FLOAT32], ["meshopt", PositionEncoding.MESHOPT]] as const) {
  describe(`updates (${name})`, () => {
    it("applies a snapshot then deltas in order", (ctx) => {
      if (enc === PositionEncoding.MESHOPT && !encoder) ctx.skip(encoderSkipReason);
      const s = new PositionState(N);
      const a = s.apply(snapshot(enc, 3, rest));
      expect(a.applied).toBe(true);
      expect(a.changed).toBeNull();
      expect(Array.from(s.positions)).toEqual(rest);
      expect(s.revision).toBe(3);

      const d = s.apply(delta(enc, 4, [1, 3], [10, 11, 12, 30, 31, 32]));
      expect(d.applied).toBe(true);
      expect(Array.from(d.changed!)).toEqual([1, 3]);
      const want = [...rest];
      want.splice(3, 3, 10, 11, 12);
      want.splice(9, 3, 30, 31, 32);
      expect(Array.from(s.positions)).toEqual(want);
      expect(s.revision).toBe(4);

      // A delta with no changed vertex still advances the revision (e.g. a converged refinement).
      expect(s.apply(delta(enc, 5, [], [])).applied).toBe(true);
      expect(s.revision).toBe(5);
    });

    it("applies a dense delta (every position, no indices)", (ctx) => {
      if (enc === PositionEncoding.MESHOPT && !encoder) ctx.skip(encoderSkipReason);
      const s = new PositionState(N);
      s.apply(snapshot(enc, 1, rest));
      const moved = rest.map((x) => x * 2);
      const p = pack(enc, moved);
      const d = s.apply(create(DeformUpdateSchema, {
        result: create(DeformResultSchema, { revision: 2n, encoding: enc, dense: true, positions: p.doubles, packedPositions: p.packed }),
      }));
      expect(d.applied).toBe(true);
      expect(d.changed).toBeNull();
      expect(Array.from(s.positions)).toEqual(moved);
      expect(s.revision).toBe(2);
    });

    it("drops stale and duplicate revisions", (ctx) => {
      if (enc === PositionEncoding.MESHOPT && !encoder) ctx.skip(encoderSkipReason);
      const s = new PositionState(N);
      s.apply(snapshot(enc, 7, rest));
      expect(s.apply(delta(enc, 7, [0], [9, 9, 9])).applied).toBe(false);
      expect(s.apply(delta(enc, 6, [0], [8, 8, 8])).applied).toBe(false);
      expect(s.apply(snapshot(enc, 5, rest.map((x) => x + 1))).applied).toBe(false);
      expect(Array.from(s.positions)).toEqual(rest);
      expect(s.revision).toBe(7);
      // A newer snapshot (after a gap) replaces everything.
      const moved = rest.map((x) => x + 2);
      expect(s.apply(snapshot(enc, 12, moved)).applied).toBe(true);
      expect(Array.from(s.positions)).toEqual(moved);
    });
  });
}

describe("updates (misc)", () => {
  it("ignores deltas before any snapshot", () => {
    const s = new PositionState(N);
    expect(s.apply(delta(PositionEncoding.UNSPECIFIED, 1, [0], [1, 2, 3])).applied).toBe(false);
    expect(s.revision).toBe(-1);
  });
  it("decodes each update by its own encoding field (old server sends doubles)", () => {
    const s = new PositionState(N);
    s.apply(snapshot(PositionEncoding.UNSPECIFIED, 0, rest));
    s.apply(delta(PositionEncoding.FLOAT32, 1, [4], [1, 2, 3]));
    expect(Array.from(s.positions.subarray(12))).toEqual([1, 2, 3]);
  });
  it("rejects a float32 payload of the wrong size and out-of-range indices", () => {
    const s = new PositionState(N);
    s.apply(snapshot(PositionEncoding.UNSPECIFIED, 0, rest));
    const bad = create(DeformUpdateSchema, {
      result: create(DeformResultSchema, { revision: 1n, encoding: PositionEncoding.FLOAT32, changedIndices: [0], packedChangedPositions: new Uint8Array(8) }),
    });
    expect(() => s.apply(bad)).toThrow(/bytes/);
    expect(() => s.apply(delta(PositionEncoding.UNSPECIFIED, 2, [N], [0, 0, 0]))).toThrow(/range/);
  });
  it("parses the encoding query value", () => {
    expect(parseEncoding("double")).toBe(PositionEncoding.UNSPECIFIED);
    expect(parseEncoding("float32")).toBe(PositionEncoding.FLOAT32);
    expect(parseEncoding(null)).toBe(PositionEncoding.MESHOPT);
    expect(encodingName(PositionEncoding.MESHOPT)).toBe("meshopt");
  });
});

describe("updateWireBytes", () => {
  it("equals the serialized size for every encoding, snapshot and delta, small and large", () => {
    const sizes = [0, 1, 5, 100, 3000]; // 3000: 3-byte length prefixes and index varints
    for (const n of sizes) {
      for (const enc of [PositionEncoding.UNSPECIFIED, PositionEncoding.FLOAT32, PositionEncoding.MESHOPT]) {
        for (const snapshot of [false, true]) {
          const indices = Array.from({ length: n }, (_, i) => i * 37 + (i % 3) * 200_000);
          const vals = Array.from({ length: 3 * n }, (_, i) => Math.sin(i) * 1e3);
          const bytes = new Uint8Array(12 * n).map((_, i) => (i * 31) & 0xff);
          const doubles = enc === PositionEncoding.UNSPECIFIED;
          const upd = create(DeformUpdateSchema, {
            isSnapshot: snapshot,
            skippedRevisions: BigInt(n),
            result: create(DeformResultSchema, {
              revision: BigInt(n + 1),
              encoding: enc,
              eTheta: 0.01,
              converged: n % 2 === 0,
              editor: "refinement",
              changedIndices: snapshot ? [] : indices,
              changedPositions: !snapshot && doubles ? vals : [],
              positions: snapshot && doubles ? vals : [],
              packedChangedPositions: !snapshot && !doubles ? bytes : new Uint8Array(0),
              packedPositions: snapshot && !doubles ? bytes : new Uint8Array(0),
            }),
          });
          const before = toBinary(DeformUpdateSchema, upd);
          expect(updateWireBytes(upd)).toBe(before.length);
          expect(toBinary(DeformUpdateSchema, upd)).toEqual(before); // the message is left as it was
        }
      }
    }
    const empty = create(DeformUpdateSchema, { isSnapshot: true });
    expect(updateWireBytes(empty)).toBe(toBinary(DeformUpdateSchema, empty).length);
  });
});
