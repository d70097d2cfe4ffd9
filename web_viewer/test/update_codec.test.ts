import { describe, expect, it } from "vitest";
import { create } from "@bufbuild/protobuf";
import { DeformResultSchema, DeformUpdateSchema, DeltaMode, VertexDeltaSchema, type VertexDelta } from "../src/gen/meshdeform/v1/deformation_pb";
import { DeltaError, StreamDecoder, applyLinkSized, linkSizedOptions, parseLinkSized } from "../src/update_codec";

// Updates made by the C++ encoder (codec/update_codec.h), with the positions its client holds
// after each: tests/codec/viewer_fixture_test.cpp writes the file and checks it decodes there too.
interface FixtureUpdate {
  mode: number; sequence: number; revision: number; vertexCount: number; verticesSent: number;
  step: number; origin: [number, number, number]; shift: number; maxError: number;
  pendingVertices: number; payload: string; positions: number[];
}
import fixtureJson from "./fixtures/update_stream.json?raw";
const fixture = JSON.parse(fixtureJson) as Record<string, FixtureUpdate[]>;

function fromBase64(text: string): Uint8Array {
  return Uint8Array.from(atob(text), (c) => c.charCodeAt(0));
}

function delta(u: FixtureUpdate): VertexDelta {
  return create(VertexDeltaSchema, {
    mode: u.mode as DeltaMode, sequence: BigInt(u.sequence), vertexCount: u.vertexCount,
    verticesSent: u.verticesSent, step: u.step, origin: { x: u.origin[0], y: u.origin[1], z: u.origin[2] },
    shift: u.shift, maxError: u.maxError, pendingVertices: u.pendingVertices,
    payload: fromBase64(u.payload),
  });
}

describe("StreamDecoder on the C++ encoder's updates", () => {
  for (const name of ["quantized", "budgeted", "lossless", "settled"]) {
    it(`reconstructs every ${name} update exactly as the encoder's client model`, () => {
      const decoder = new StreamDecoder();
      expect(fixture[name].length).toBeGreaterThanOrEqual(4);
      for (const u of fixture[name]) {
        decoder.apply(delta(u), u.revision);
        expect(decoder.sequence).toBe(u.sequence);
        expect(decoder.complete).toBe(u.pendingVertices === 0);
        expect(decoder.positions.length).toBe(u.positions.length);
        for (let i = 0; i < u.positions.length; i++) {
          if (decoder.positions[i] !== u.positions[i]) {
            throw new Error(`${name} update ${u.sequence}: value ${i} is ${decoder.positions[i]}, expected ${u.positions[i]}`);
          }
        }
      }
    });
  }

  it("keeps the sign of a lossless -0", () => {
    const decoder = new StreamDecoder();
    for (const u of fixture.lossless) decoder.apply(delta(u), u.revision);
    expect(Object.is(decoder.positions[5 * 3 + 1], -0)).toBe(true);
  });

  it("refuses an update out of sequence, a truncated payload and another stream's grid", () => {
    const [first, second] = fixture.quantized;
    const decoder = new StreamDecoder();
    expect(() => decoder.apply(delta(second), second.revision)).toThrow(DeltaError);
    decoder.apply(delta(first), first.revision);
    const truncated = delta(second);
    truncated.payload = truncated.payload.subarray(0, truncated.payload.length >> 1);
    expect(() => decoder.apply(truncated, second.revision)).toThrow(DeltaError);
    const moved = delta(second);
    moved.step *= 2;
    expect(() => decoder.apply(moved, second.revision)).toThrow(DeltaError);
    const miscounted = delta(second);
    miscounted.verticesSent += 1;
    expect(() => decoder.apply(miscounted, second.revision)).toThrow(DeltaError);
    // The state is unchanged by what it refused: the real next update still applies.
    decoder.apply(delta(second), second.revision);
    expect(decoder.sequence).toBe(2);
  });

  it("starts over on a new stream's first update (a reconnect)", () => {
    const decoder = new StreamDecoder();
    for (const u of fixture.quantized) decoder.apply(delta(u), u.revision);
    const again = fixture.quantized[0];
    decoder.apply(delta(again), again.revision);
    expect(decoder.sequence).toBe(1);
    expect(Array.from(decoder.positions)).toEqual(again.positions);
  });
});

describe("applyLinkSized", () => {
  it("writes the reconstruction into the view's positions, continuations included", () => {
    const updates = fixture.budgeted;
    const state = { positions: new Float32Array(updates[0].vertexCount * 3), revision: -1 };
    for (const u of updates) {
      const update = create(DeformUpdateSchema, {
        result: create(DeformResultSchema, { revision: BigInt(u.revision) }),
        delta: delta(u),
      });
      expect(applyLinkSized(state, update).applied).toBe(true);
      expect(state.revision).toBe(u.revision);
      expect(state.positions[3 * 7 + 2]).toBeCloseTo(u.positions[3 * 7 + 2], 6);
    }
  });
});

describe("the URL's choice", () => {
  it("parses updates, tolerance and budget and maps them to UpdateOptions", () => {
    const choice = parseLinkSized(new URLSearchParams("updates=quantized&tolerance=0.001&budget=150000"));
    expect(choice).toEqual({ mode: "quantized", relativeTolerance: 0.001, maxUpdateBytes: 150000, losslessSettled: false });
    const options = linkSizedOptions(choice);
    expect(options?.mode).toBe(DeltaMode.QUANTIZED);
    expect(options?.relativeTolerance).toBe(0.001);
    expect(options?.maxUpdateBytes).toBe(150000);
    expect(linkSizedOptions(parseLinkSized(new URLSearchParams("")))).toBeUndefined();
    expect(parseLinkSized(new URLSearchParams("updates=lossless&tolerance=5&budget=10"))).toEqual({
      mode: "lossless", relativeTolerance: 0, maxUpdateBytes: 0, losslessSettled: false,
    });
    // exact_settled=1: quantized streams ask for settled revisions lossless (lossless ones are
    // exact already).
    const settled = parseLinkSized(new URLSearchParams("updates=quantized&exact_settled=1"));
    expect(settled.losslessSettled).toBe(true);
    expect(linkSizedOptions(settled)?.losslessSettled).toBe(true);
    expect(parseLinkSized(new URLSearchParams("updates=lossless&exact_settled=1")).losslessSettled).toBe(false);
  });

  it("shows a settled revision exactly, then goes on quantized from it", () => {
    const decoder = new StreamDecoder();
    const stream = fixture.settled;
    expect(stream.some((u) => u.mode === DeltaMode.LOSSLESS)).toBe(true);
    expect(stream.some((u, k) => k > 0 && u.mode === DeltaMode.QUANTIZED && stream[k - 1].mode === DeltaMode.LOSSLESS)).toBe(true);
    for (const u of stream) {
      decoder.apply(delta(u), u.revision);
      expect(Array.from(decoder.positions)).toEqual(u.positions);
    }
  });
});
