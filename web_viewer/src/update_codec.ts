// Link-sized Watch updates (issue 45): decodes meshdeform.v1.VertexDelta, the server's
// per-stream deltas (quantized within a stated tolerance, or lossless), in the format of
// codec/update_codec.h. Self-contained: the rest of the viewer needs two hooks, the request's
// `updates` (linkSizedOptions) and PositionState.apply handing delta updates to applyLinkSized.
//
// Payload (one zstd frame; LEB128 varints):
//   byte version (1), byte flags (bit 0: every vertex in order, no index list), varint n,
//   n index gaps unless bit 0, then per axis x, y, z:
//     quantized: n zigzag varints, d_i - d_{i-1}: the vertex's grid delta in units of 2^shift;
//     lossless:  8 planes (byte 7 down to 0) of n bytes: the XOR of old and new double bits.
// A quantized stream may carry lossless updates (its settled revisions, UpdateOptions.
// lossless_settled): they keep the stream's grid in the header, XOR the positions shown, and
// leave the grid coordinates as they were; a later quantized update puts a vertex it sends back
// on the grid.
import { create } from "@bufbuild/protobuf";
import { decompress } from "fzstd";
import { DeltaMode, UpdateOptionsSchema, type DeformUpdate, type UpdateOptions, type VertexDelta } from "./gen/meshdeform/v1/deformation_pb";

/**
 * The viewer's ask, from the page URL:
 * ?updates=quantized|lossless[&tolerance=X][&budget=BYTES][&exact_settled=1].
 */
export interface LinkSizedChoice {
  mode: "off" | "quantized" | "lossless";
  relativeTolerance: number; // 0: the server's default (1e-4 of the bounding-box diagonal)
  maxUpdateBytes: number; // 0: no budget
  losslessSettled: boolean; // quantized: the result after a release, once settled, exactly
}

export function parseLinkSized(params: URLSearchParams): LinkSizedChoice {
  const m = (params.get("updates") ?? "off").toLowerCase();
  const mode = m === "quantized" || m === "lossless" ? m : "off";
  const tol = Number(params.get("tolerance") ?? "0");
  const budget = Math.floor(Number(params.get("budget") ?? "0"));
  return {
    mode,
    relativeTolerance: Number.isFinite(tol) && tol > 0 && tol <= 0.1 ? tol : 0,
    maxUpdateBytes: Number.isFinite(budget) && budget >= 1024 ? budget : 0,
    losslessSettled: mode === "quantized" && params.get("exact_settled") === "1",
  };
}

/** The WatchRequest.updates for a choice (undefined when off: the plain updates). */
export function linkSizedOptions(choice: LinkSizedChoice): UpdateOptions | undefined {
  if (choice.mode === "off") return undefined;
  return create(UpdateOptionsSchema, {
    mode: choice.mode === "lossless" ? DeltaMode.LOSSLESS : DeltaMode.QUANTIZED,
    relativeTolerance: choice.relativeTolerance,
    maxUpdateBytes: choice.maxUpdateBytes,
    losslessSettled: choice.losslessSettled,
  });
}

export class DeltaError extends Error {}

/** Refuses frames larger than an update of `count` vertices can be (no decompression bombs). */
function maxRawBytes(mode: DeltaMode, count: number): number {
  return 12 + count * 5 + (mode === DeltaMode.QUANTIZED ? count * 30 : count * 24);
}

/** A bounded reader of the decompressed payload. */
class Reader {
  at = 0;
  constructor(readonly bytes: Uint8Array) {}
  byte(): number {
    if (this.at >= this.bytes.length) throw new DeltaError("payload truncated");
    return this.bytes[this.at++];
  }
  /** A varint as a JS number (exact below 2^53, all a grid value can be). */
  varint(): number {
    let value = 0;
    let scale = 1;
    for (let i = 0; i < 10; i++) {
      const b = this.byte();
      value += (b & 0x7f) * scale;
      if ((b & 0x80) === 0) return value;
      scale *= 128;
    }
    throw new DeltaError("varint too long");
  }
}

function unzigzag(v: number): number {
  return v % 2 === 1 ? -(v + 1) / 2 : v / 2;
}

/**
 * A lossless payload's values from `at` on (per axis, 8 byte planes from the most significant,
 * each with a byte per vertex sent): XORs them into the bits of `values` (xyz per vertex).
 */
function xorPlanes(values: Float64Array, raw: Uint8Array, at: number, index: Uint32Array): void {
  const n = index.length;
  if (raw.length - at !== n * 24) throw new DeltaError("payload size disagrees with its vertex count");
  const bytes = new Uint8Array(values.buffer); // little-endian, as every browser is
  for (let c = 0; c < 3; c++) {
    for (let b = 7; b >= 0; b--) {
      for (let k = 0; k < n; k++) bytes[(3 * index[k] + c) * 8 + b] ^= raw[at++];
    }
  }
}

/** The positions one Watch stream's deltas have built. A sequence-1 update starts over. */
export class StreamDecoder {
  sequence = 0;
  revision = 0;
  complete = false;
  private grid = false; // a quantized stream (its lossless updates carry the grid too)
  private count = 0;
  private step = 0;
  private origin: [number, number, number] = [0, 0, 0];
  private q: Float64Array = new Float64Array(0); // quantized: integer grid coordinates
  /** The reconstructed positions, xyz per vertex, as doubles. */
  positions: Float64Array = new Float64Array(0);

  apply(delta: VertexDelta, revision: number): void {
    const sequence = Number(delta.sequence);
    if (sequence === 1) this.sequence = 0; // a new stream (the viewer reconnected)
    if (sequence !== this.sequence + 1) {
      throw new DeltaError(`update ${sequence} out of sequence (expected ${this.sequence + 1})`);
    }
    const mode = delta.mode;
    if (mode !== DeltaMode.QUANTIZED && mode !== DeltaMode.LOSSLESS) throw new DeltaError(`unknown delta mode ${mode}`);
    const count = delta.vertexCount;
    const origin: [number, number, number] = [delta.origin?.x ?? 0, delta.origin?.y ?? 0, delta.origin?.z ?? 0];
    const grid = mode === DeltaMode.QUANTIZED || delta.step !== 0;
    if (this.sequence > 0 && (grid !== this.grid || count !== this.count ||
        (grid && (delta.step !== this.step || origin.some((o, i) => o !== this.origin[i]))))) {
      throw new DeltaError("update of another stream (count, mode or grid changed)");
    }
    if (grid && (!(delta.step > 0) || !Number.isFinite(delta.step) || delta.shift > 24 ||
        (mode === DeltaMode.LOSSLESS && delta.shift !== 0))) {
      throw new DeltaError("bad grid in update header");
    }
    let raw: Uint8Array;
    try {
      raw = decompress(delta.payload);
    } catch (e) {
      throw new DeltaError(`payload does not decompress: ${e}`);
    }
    if (raw.length > maxRawBytes(mode, count)) throw new DeltaError("payload larger than an update can be");
    const r = new Reader(raw);
    if (r.byte() !== 1) throw new DeltaError("unknown payload version");
    const flags = r.byte();
    if ((flags & ~1) !== 0) throw new DeltaError("unknown payload flags");
    const n = r.varint();
    if (n > count || n !== delta.verticesSent) throw new DeltaError("payload vertex count disagrees with its header");
    const index = new Uint32Array(n);
    if (flags & 1) {
      if (n !== count) throw new DeltaError("payload says every vertex but carries fewer");
      for (let k = 0; k < n; k++) index[k] = k;
    } else {
      let previous = -1;
      for (let k = 0; k < n; k++) {
        const v = previous + 1 + r.varint();
        if (v >= count) throw new DeltaError("vertex index out of range");
        index[k] = v;
        previous = v;
      }
    }
    const fresh = this.sequence === 0;
    // What the client shows: a grid stream starts with every vertex at the origin, a lossless
    // one at the doubles of bit pattern 0.
    const shown = fresh ? new Float64Array(count * 3) : this.positions.slice();
    if (fresh && grid) for (let i = 0; i < count * 3; i++) shown[i] = origin[i % 3];
    if (mode === DeltaMode.QUANTIZED) {
      const q = fresh ? new Float64Array(count * 3) : this.q.slice();
      const unit = 2 ** delta.shift;
      for (let c = 0; c < 3; c++) {
        let previous = 0;
        for (let k = 0; k < n; k++) {
          const d = previous + unzigzag(r.varint());
          previous = d;
          q[3 * index[k] + c] += d * unit;
        }
      }
      if (r.at !== raw.length) throw new DeltaError("payload has trailing bytes");
      // The vertices sent show their grid points; the others keep what they showed.
      for (let k = 0; k < n; k++) {
        for (let c = 0; c < 3; c++) {
          const i = 3 * index[k] + c;
          shown[i] = origin[c] + q[i] * delta.step;
        }
      }
      this.q = q;
      this.positions = shown;
    } else {
      // Lossless: against the positions shown; a grid stream's grid coordinates stay.
      xorPlanes(shown, raw, r.at, index);
      if (fresh && grid) this.q = new Float64Array(count * 3);
      this.positions = shown;
    }
    this.sequence = sequence;
    this.revision = revision;
    this.complete = delta.pendingVertices === 0;
    this.grid = grid;
    this.count = count;
    this.step = delta.step;
    this.origin = origin;
  }
}

/** What PositionState needs to know after applying a delta update. */
export interface LinkSizedApplied {
  applied: boolean;
  revision: number;
}

const decoders = new WeakMap<object, StreamDecoder>();

/**
 * Applies a link-sized update to `state` (any object with `positions` and `revision`): every
 * vertex is rewritten from the stream's decoder (the delta is against what this stream delivered,
 * continuations included, so none may be dropped even when its revision is not newer).
 */
export function applyLinkSized(state: { positions: Float32Array; revision: number }, update: DeformUpdate): LinkSizedApplied {
  const delta = update.delta;
  const r = update.result;
  if (!delta || !r) throw new DeltaError("not a link-sized update");
  let decoder = decoders.get(state);
  if (!decoder || Number(delta.sequence) === 1) {
    decoder = new StreamDecoder();
    decoders.set(state, decoder);
  }
  const revision = Number(r.revision);
  decoder.apply(delta, revision);
  if (decoder.positions.length !== state.positions.length) {
    throw new DeltaError(`update of ${decoder.positions.length / 3} vertices for a mesh of ${state.positions.length / 3}`);
  }
  state.positions.set(decoder.positions);
  state.revision = revision;
  return { applied: true, revision };
}
