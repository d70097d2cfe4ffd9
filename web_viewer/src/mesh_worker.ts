// The Watch stream's worker (src/frames.ts says why): reads the stream, applies every update in
// revision order, and posts the page at most one frame at a time with the newest positions, their
// normals and bounding sphere, and the heat map's per-vertex values when the map is on.
import { Code, ConnectError, createContextValues } from "@connectrpc/connect";
import { kSessionId, makeClient } from "./client";
import { CoarseLevelState } from "./coarse";
import { cornerAngles, faceAreas2, vertexAreaLog, vertexDistortion } from "./distortion";
import { FrameGate, type FromWorker, type HeatMetric, type ToWorker, type UpdateInfo } from "./frames";
import { boundingSphere, vertexNormals } from "./geometry";
import { decoderReady, encodingName, PositionState, updateWireBytes } from "./updates";
import { linkSizedOptions } from "./update_codec";
import { DeltaMode, type UpdateOptions } from "./gen/meshdeform/v1/deformation_pb";

interface Open {
  sessionId: string;
  token: string;
  encoding: number;
  /** Link-sized updates (issue 45): undefined for positions as `encoding` says. */
  updates: UpdateOptions | undefined;
  indices: Uint32Array;
  restAngles: Float32Array | null;
  restAreas2: Float64Array | null;
  rest: Float32Array;
  state: PositionState;
  /** Watch coarse_preview, and the newest update's coarse level. */
  coarsePreview: boolean;
  coarse: CoarseLevelState;
  /** Page clock = worker clock + offset. */
  offset: number;
}

let open: Open | null = null;
let heatMetric: HeatMetric | null = null;
const gate = new FrameGate();
let spare: { positions: Float32Array; normals: Float32Array; heat: Float32Array | null } | null = null;

function post(m: FromWorker, transfer: Transferable[] = []): void {
  // (Typed with the DOM's Window; a worker's postMessage takes the same options form.)
  self.postMessage(m, { transfer });
}

function heatValues(o: Open, out: Float32Array | null): Float32Array | null {
  if (!heatMetric) return null;
  const n = o.state.vertexCount;
  let v: Float32Array;
  if (heatMetric === "area") {
    o.restAreas2 ??= faceAreas2(o.rest, o.indices);
    v = vertexAreaLog(o.restAreas2, o.state.positions, o.indices, n);
    for (let i = 0; i < n; i++) v[i] = Math.abs(v[i]);
  } else {
    o.restAngles ??= cornerAngles(o.rest, o.indices);
    v = vertexDistortion(o.restAngles, o.state.positions, o.indices, n);
  }
  if (out && out.length === n) {
    out.set(v);
    return out;
  }
  return v;
}

function flush(): void {
  const o = open;
  if (!o || !o.state.hasSnapshot) return;
  const updates = gate.take();
  if (!updates) return;
  const t0 = performance.now();
  const n3 = o.state.positions.length;
  const positions = spare && spare.positions.length === n3 ? spare.positions : new Float32Array(n3);
  const normals = spare && spare.normals.length === n3 ? spare.normals : new Float32Array(n3);
  positions.set(o.state.positions);
  vertexNormals(positions, o.indices, normals);
  const heat = heatValues(o, spare?.heat ?? null);
  spare = null;
  const coarse = o.coarse.frame();
  const transfer: Transferable[] = [positions.buffer, normals.buffer];
  if (heat) transfer.push(heat.buffer);
  if (coarse) transfer.push(coarse.positions.buffer, coarse.normals.buffer);
  post({
    type: "frame", revision: o.state.revision, positions, normals, sphere: boundingSphere(positions), heat, heatMetric,
    updates, workMs: performance.now() - t0, coarse,
  }, transfer);
}

async function watch(o: Open): Promise<void> {
  await decoderReady();
  const client = makeClient(self.location.origin);
  let backoff = 250;
  for (;;) {
    if (open !== o) return;
    try {
      const stream = client.watch(
        { sessionId: o.sessionId, token: o.token, encoding: o.encoding, updates: o.updates, coarsePreview: o.coarsePreview },
        { contextValues: createContextValues().set(kSessionId, o.sessionId) },
      );
      for await (const upd of stream) {
        if (open !== o) return;
        backoff = 250;
        const r = upd.result;
        if (!r) continue;
        const bytes = updateWireBytes(upd);
        let applied;
        try {
          applied = o.state.apply(upd);
        } catch (e) {
          post({ type: "bad", message: String((e as Error)?.message ?? e) });
          continue;
        }
        if (!applied.applied) continue;
        try {
          // A continuation carries more of the same revision: its coarse level stands.
          if (!upd.continuation) o.coarse.apply(upd.coarse);
        } catch (e) {
          // The full positions stand; only the preview of this update is lost.
          o.coarse.apply(undefined);
          post({ type: "bad", message: String((e as Error)?.message ?? e) });
        }
        const info: UpdateInfo = {
          revision: Number(r.revision), bytes, isSnapshot: upd.isSnapshot,
          // Link-sized updates (issue 45) name their delta mode instead of a position encoding.
          encoding: upd.delta ? (upd.delta.mode === DeltaMode.LOSSLESS ? "lossless delta" : "quantized delta") : encodingName(r.encoding),
          refinement: r.refinement, converged: r.converged, eTheta: r.eTheta, ePhi: r.ePhi, areaLogRms: r.areaLogRms,
          iterations: r.iterations, pcgIterations: r.pcgIterations, solveSeconds: r.solveSeconds,
          appliedAt: performance.now() + o.offset,
        };
        gate.update(info);
        flush();
      }
      // Ends OK only when the session is closed: nothing to reconnect to.
      if (open === o) post({ type: "end" });
      return;
    } catch (e) {
      if (open !== o) return;
      const err = ConnectError.from(e);
      if (err.code === Code.NotFound || err.code === Code.PermissionDenied || err.code === Code.InvalidArgument) {
        post({ type: "error", code: err.code, message: err.message, rawMessage: err.rawMessage });
        return;
      }
      post({ type: "status", text: `Connection lost — reconnecting in ${(backoff / 1000).toFixed(1)} s` });
      await new Promise((r) => setTimeout(r, backoff));
      backoff = Math.min(backoff * 2, 10_000);
    }
  }
}

self.onmessage = (ev: MessageEvent<ToWorker>) => {
  const m = ev.data;
  if (m.type === "open") {
    heatMetric = m.heat;
    const state = new PositionState(m.vertexCount);
    open = {
      sessionId: m.sessionId, token: m.token, encoding: m.encoding, updates: linkSizedOptions(m.updates), indices: m.indices, rest: m.rest,
      restAngles: null, restAreas2: null, state, coarsePreview: m.coarse, coarse: new CoarseLevelState(m.vertexCount), offset: performance.timeOrigin - m.pageTimeOrigin,
    };
    void watch(open);
  } else if (m.type === "ack") {
    spare = { positions: m.positions, normals: m.normals, heat: m.heat };
    gate.ack();
    flush();
  } else if (m.type === "heat") {
    heatMetric = m.metric;
    gate.heat();
    flush();
  }
};
