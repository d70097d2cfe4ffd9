// Minimal GLB reader for the server's own export: one mesh, one primitive, float32 POSITION and
// uint32 (or uint16) indices. The vertex order matches the server's indices, which the viewer
// relies on to apply Watch deltas.

export interface GlbMesh {
  positions: Float32Array;
  indices: Uint32Array;
}

const MAGIC = 0x46546c67; // "glTF"
const CHUNK_JSON = 0x4e4f534a;
const CHUNK_BIN = 0x004e4942;

interface Accessor {
  bufferView?: number;
  byteOffset?: number;
  componentType: number;
  count: number;
  type: string;
}
interface BufferView {
  byteOffset?: number;
  byteLength: number;
  byteStride?: number;
}

export function parseGlb(data: Uint8Array): GlbMesh {
  const dv = new DataView(data.buffer, data.byteOffset, data.byteLength);
  if (data.byteLength < 20 || dv.getUint32(0, true) !== MAGIC) throw new Error("not a GLB file");
  if (dv.getUint32(4, true) !== 2) throw new Error("unsupported glTF version");
  const total = Math.min(dv.getUint32(8, true), data.byteLength);
  let off = 12;
  let json: any = null;
  let bin: Uint8Array | null = null;
  while (off + 8 <= total) {
    const len = dv.getUint32(off, true);
    const type = dv.getUint32(off + 4, true);
    const body = data.subarray(off + 8, off + 8 + len);
    if (type === CHUNK_JSON) json = JSON.parse(new TextDecoder().decode(body));
    else if (type === CHUNK_BIN && !bin) bin = body;
    off += 8 + len;
  }
  if (!json) throw new Error("GLB without JSON chunk");
  if (!bin) throw new Error("GLB without BIN chunk");
  const prim = json.meshes?.[0]?.primitives?.[0];
  if (!prim || prim.attributes?.POSITION === undefined) throw new Error("GLB without a POSITION primitive");
  const mode = prim.mode ?? 4;
  if (mode !== 4) throw new Error(`unsupported primitive mode ${mode}`);

  const read = (ai: number): { acc: Accessor; bytes: Uint8Array; stride: number } => {
    const acc: Accessor = json.accessors[ai];
    const bv: BufferView = json.bufferViews[acc.bufferView ?? -1];
    if (!bv) throw new Error("accessor without bufferView");
    const start = (bv.byteOffset ?? 0) + (acc.byteOffset ?? 0);
    return { acc, bytes: bin!.subarray(start, (bv.byteOffset ?? 0) + bv.byteLength), stride: bv.byteStride ?? 0 };
  };

  const pos = read(prim.attributes.POSITION);
  if (pos.acc.componentType !== 5126 || pos.acc.type !== "VEC3") throw new Error("POSITION must be float32 VEC3");
  const n = pos.acc.count;
  const positions = new Float32Array(n * 3);
  const pdv = new DataView(pos.bytes.buffer, pos.bytes.byteOffset, pos.bytes.byteLength);
  const ps = pos.stride || 12;
  for (let i = 0; i < n; i++) for (let c = 0; c < 3; c++) positions[i * 3 + c] = pdv.getFloat32(i * ps + c * 4, true);

  let indices: Uint32Array;
  if (prim.indices === undefined) {
    indices = new Uint32Array(n);
    for (let i = 0; i < n; i++) indices[i] = i;
  } else {
    const ix = read(prim.indices);
    const m = ix.acc.count;
    const idv = new DataView(ix.bytes.buffer, ix.bytes.byteOffset, ix.bytes.byteLength);
    indices = new Uint32Array(m);
    const ct = ix.acc.componentType;
    for (let i = 0; i < m; i++) {
      indices[i] =
        ct === 5125 ? idv.getUint32(i * 4, true) : ct === 5123 ? idv.getUint16(i * 2, true) : ct === 5121 ? idv.getUint8(i) : NaN;
    }
    if (ct !== 5125 && ct !== 5123 && ct !== 5121) throw new Error(`unsupported index type ${ct}`);
    for (let i = 0; i < m; i++) if (indices[i] >= n) throw new Error("index out of range");
  }
  return { positions, indices };
}

/** Builds a GLB (used by the tests, and handy for debugging). */
export function buildGlb(positions: Float32Array, indices: Uint32Array): Uint8Array {
  const pad4 = (x: number) => (x + 3) & ~3;
  const posBytes = positions.byteLength;
  const idxBytes = indices.byteLength;
  const binLen = pad4(posBytes + idxBytes);
  const gltf = {
    asset: { version: "2.0" },
    buffers: [{ byteLength: binLen }],
    bufferViews: [
      { buffer: 0, byteOffset: 0, byteLength: posBytes, target: 34962 },
      { buffer: 0, byteOffset: posBytes, byteLength: idxBytes, target: 34963 },
    ],
    accessors: [
      { bufferView: 0, componentType: 5126, count: positions.length / 3, type: "VEC3" },
      { bufferView: 1, componentType: 5125, count: indices.length, type: "SCALAR" },
    ],
    meshes: [{ primitives: [{ attributes: { POSITION: 0 }, indices: 1, mode: 4 }] }],
    nodes: [{ mesh: 0 }],
    scenes: [{ nodes: [0] }],
    scene: 0,
  };
  let jsonBytes = new TextEncoder().encode(JSON.stringify(gltf));
  const jsonLen = pad4(jsonBytes.length);
  const total = 12 + 8 + jsonLen + 8 + binLen;
  const out = new Uint8Array(total);
  const dv = new DataView(out.buffer);
  dv.setUint32(0, MAGIC, true);
  dv.setUint32(4, 2, true);
  dv.setUint32(8, total, true);
  dv.setUint32(12, jsonLen, true);
  dv.setUint32(16, CHUNK_JSON, true);
  out.fill(0x20, 20, 20 + jsonLen);
  out.set(jsonBytes, 20);
  const b = 20 + jsonLen;
  dv.setUint32(b, binLen, true);
  dv.setUint32(b + 4, CHUNK_BIN, true);
  out.set(new Uint8Array(positions.buffer, positions.byteOffset, posBytes), b + 8);
  out.set(new Uint8Array(indices.buffer, indices.byteOffset, idxBytes), b + 8 + posBytes);
  jsonBytes = new Uint8Array(0);
  return out;
}
