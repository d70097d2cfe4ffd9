// Applies the Watch stream to a flat Float32Array of positions, in revision order.
// Every DeformResult is decoded by its own `encoding` field: an older server ignores the
// requested encoding and sends doubles (encoding UNSPECIFIED).
import { toBinary } from "@bufbuild/protobuf";
import { MeshoptDecoder } from "meshoptimizer/decoder";
import { DeformResultSchema, DeformUpdateSchema, PositionEncoding, type DeformResult, type DeformUpdate } from "./gen/meshdeform/v1/deformation_pb";
import { applyLinkSized } from "./update_codec";

export type EncodingName = "double" | "float32" | "meshopt";

export function parseEncoding(s: string | null | undefined): PositionEncoding {
  switch ((s ?? "").toLowerCase()) {
    case "double":
      return PositionEncoding.UNSPECIFIED;
    case "float32":
      return PositionEncoding.FLOAT32;
    default:
      return PositionEncoding.MESHOPT;
  }
}

export function encodingName(e: PositionEncoding): EncodingName {
  return e === PositionEncoding.FLOAT32 ? "float32" : e === PositionEncoding.MESHOPT ? "meshopt" : "double";
}

/** Call once before decoding MESHOPT (the decoder compiles its wasm asynchronously). */
export function decoderReady(): Promise<void> {
  return MeshoptDecoder.ready;
}

/** `count` vertices (xyz each) from packed bytes or doubles, per `encoding`. */
export function decodePositions(
  encoding: PositionEncoding,
  doubles: number[],
  packed: Uint8Array,
  count: number,
): Float32Array {
  if (encoding === PositionEncoding.FLOAT32) {
    if (packed.length !== count * 12) throw new Error(`float32 positions: ${packed.length} bytes for ${count} vertices`);
    // Copy so the view is 4-byte aligned whatever the protobuf buffer offset was.
    const out = new Float32Array(count * 3);
    new Uint8Array(out.buffer).set(packed);
    if (!littleEndian) {
      const dv = new DataView(packed.buffer, packed.byteOffset, packed.byteLength);
      for (let i = 0; i < count * 3; i++) out[i] = dv.getFloat32(i * 4, true);
    }
    return out;
  }
  if (encoding === PositionEncoding.MESHOPT) {
    const out = new Float32Array(count * 3);
    if (count > 0) MeshoptDecoder.decodeVertexBuffer(new Uint8Array(out.buffer), count, 12, packed);
    return out;
  }
  if (doubles.length !== count * 3) throw new Error(`double positions: ${doubles.length} values for ${count} vertices`);
  return Float32Array.from(doubles);
}

const littleEndian = new Uint8Array(new Uint16Array([1]).buffer)[0] === 1;

export interface Applied {
  applied: boolean;
  /** null after a snapshot (every vertex changed), else the changed indices. */
  changed: Uint32Array | null;
  result: DeformResult;
}

/** Holds the rendered positions and the revision they show. */
export class PositionState {
  positions: Float32Array;
  revision = -1;

  constructor(readonly vertexCount: number) {
    this.positions = new Float32Array(vertexCount * 3);
  }

  get hasSnapshot(): boolean {
    return this.revision >= 0;
  }

  /** Applies one update; drops it if its revision is not newer than the one shown. */
  apply(update: DeformUpdate): Applied {
    const r = update.result;
    if (!r) throw new Error("update without result");
    // Link-sized: a delta against this stream's own updates (continuations too), every vertex.
    if (update.delta) return { applied: applyLinkSized(this, update).applied, changed: null, result: r };
    const rev = Number(r.revision);
    if (rev <= this.revision) return { applied: false, changed: null, result: r };
    if (update.isSnapshot) {
      const p = decodePositions(r.encoding, r.positions, r.packedPositions, this.vertexCount);
      this.positions.set(p);
      this.revision = rev;
      return { applied: true, changed: null, result: r };
    }
    // A delta is relative to the previous revision: it is only valid on top of some snapshot.
    if (!this.hasSnapshot) return { applied: false, changed: null, result: r };
    if (r.dense) {
      // Nearly every vertex moved: the server sent the delta dense (all positions, no indices).
      this.positions.set(decodePositions(r.encoding, r.positions, r.packedPositions, this.vertexCount));
      this.revision = rev;
      return { applied: true, changed: null, result: r };
    }
    const idx = Uint32Array.from(r.changedIndices);
    const p = decodePositions(r.encoding, r.changedPositions, r.packedChangedPositions, idx.length);
    const dst = this.positions;
    for (let i = 0; i < idx.length; i++) {
      const v = idx[i];
      if (v >= this.vertexCount) throw new Error(`changed index ${v} out of range`);
      dst[v * 3] = p[i * 3];
      dst[v * 3 + 1] = p[i * 3 + 1];
      dst[v * 3 + 2] = p[i * 3 + 2];
    }
    this.revision = rev;
    return { applied: true, changed: idx, result: r };
  }
}

function varintSize(v: number): number {
  let n = 1;
  while (v >= 0x80) {
    v = Math.floor(v / 128);
    n++;
  }
  return n;
}

/** Bytes of a length-delimited field with `payload` bytes (omitted when empty, as proto3 does). */
function lengthDelimited(tagBytes: number, payload: number): number {
  return payload === 0 ? 0 : tagBytes + varintSize(payload) + payload;
}

/**
 * The serialized size of `upd` (what the wire carried), without serializing its positions: re-encoding a
 * delta of 10^5 doubles to count it cost the viewer more than decoding it (40k vertices: most of the main
 * thread while dragging). The big repeated and bytes fields of the result are counted from their lengths,
 * everything else by serializing the update with them emptied (restored before returning).
 */
export function updateWireBytes(upd: DeformUpdate): number {
  const r = upd.result;
  if (!r) return toBinary(DeformUpdateSchema, upd).length;
  const { changedIndices, changedPositions, positions, packedChangedPositions, packedPositions } = r;
  let indexBytes = 0;
  for (const i of changedIndices) indexBytes += varintSize(i);
  // Fields 3-5 have one-byte tags, 17 and 18 two-byte ones; all are packed or bytes (wire type 2).
  const big =
    lengthDelimited(1, indexBytes) +
    lengthDelimited(1, 8 * changedPositions.length) +
    lengthDelimited(1, 8 * positions.length) +
    lengthDelimited(2, packedChangedPositions.length) +
    lengthDelimited(2, packedPositions.length);
  const empty = new Uint8Array(0);
  r.changedIndices = [];
  r.changedPositions = [];
  r.positions = [];
  r.packedChangedPositions = empty;
  r.packedPositions = empty;
  try {
    // DeformUpdate = the result (field 1: tag, length, payload) + its own small fields.
    const payload = toBinary(DeformResultSchema, r).length + big;
    const outside = toBinary(DeformUpdateSchema, { ...upd, result: undefined }).length;
    return outside + 1 + varintSize(payload) + payload;
  } finally {
    r.changedIndices = changedIndices;
    r.changedPositions = changedPositions;
    r.positions = positions;
    r.packedChangedPositions = packedChangedPositions;
    r.packedPositions = packedPositions;
  }
}
