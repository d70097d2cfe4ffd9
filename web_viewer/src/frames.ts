// The Watch stream off the page's main thread (issue 44): a worker (src/mesh_worker.ts) reads the
// stream, decodes and applies every update, computes normals (and the heat map's values), and
// hands the page at most one frame at a time: while the page has not taken the last one, newer
// updates are applied in the worker and the frames in between are dropped, never queued. The
// page's pointer input never waits on a 187k-vertex update. This file: the messages, and the
// gate that decides when a frame goes out (pure, tested).

import type { CoarseFrame } from "./coarse";
import type { LinkSizedChoice } from "./update_codec";

export type HeatMetric = "angle" | "area";

/** What the page needs to know of every update (rendered or dropped). */
export interface UpdateInfo {
  revision: number;
  bytes: number;
  encoding: string;
  isSnapshot: boolean;
  refinement: boolean;
  converged: boolean;
  eTheta: number;
  ePhi: number;
  areaLogRms: number;
  iterations: number;
  pcgIterations: number;
  solveSeconds: number;
  /** When the worker had it applied, on the page's clock (performance.now()). */
  appliedAt: number;
}

/** Page -> worker. */
export type ToWorker =
  | {
    type: "open"; origin: string; sessionId: string; token: string; encoding: number; vertexCount: number;
    /** Link-sized updates (issue 45; the page's ?updates=): the worker asks the Watch for them. */
    updates: LinkSizedChoice;
    /** Ask the Watch for the coarse level of multiresolution moves (drawn during a drag). */
    coarse: boolean;
    indices: Uint32Array; rest: Float32Array; heat: HeatMetric | null; pageTimeOrigin: number;
  }
  /** The page drew the last frame: these buffers may be filled again. */
  | { type: "ack"; positions: Float32Array; normals: Float32Array; heat: Float32Array | null }
  | { type: "heat"; metric: HeatMetric | null };

/** Worker -> page. */
export type FromWorker =
  | {
    type: "frame"; revision: number; positions: Float32Array; normals: Float32Array; sphere: { center: [number, number, number]; radius: number };
    heat: Float32Array | null; heatMetric: HeatMetric | null; updates: UpdateInfo[]; workMs: number;
    /** The newest update's coarse level (a multiresolution move), else null (src/coarse.ts). */
    coarse: CoarseFrame | null;
  }
  | { type: "status"; text: string }
  | { type: "bad"; message: string }
  | { type: "error"; code: number; message: string; rawMessage: string }
  | { type: "end" };

/** One frame out at a time: `ready` after the page's ack, `dirty` after a new update. */
export class FrameGate {
  private waiting = false;
  private dirty = false;
  private infos: UpdateInfo[] = [];
  private heatChanged = false;

  /** An update was applied. */
  update(info: UpdateInfo): void {
    this.infos.push(info);
    this.dirty = true;
  }

  /** The heat map's metric changed: the next frame must carry it even without an update. */
  heat(): void {
    this.heatChanged = true;
  }

  /** The page took the last frame. */
  ack(): void {
    this.waiting = false;
  }

  /** Whether a frame should go out now; if so, takes the updates it reports. */
  take(): UpdateInfo[] | null {
    if (this.waiting || (!this.dirty && !this.heatChanged)) return null;
    const out = this.infos;
    this.infos = [];
    this.dirty = false;
    this.heatChanged = false;
    this.waiting = true;
    return out;
  }

  get pending(): number {
    return this.infos.length;
  }
}
