// The Watch stream's frames on screen: opens the session's stream (app/watch_stream.ts) and
// applies each frame the worker hands over (positions, revision, heat values, the coarse level of
// a drag, the metrics and result panels, the page's frame measurements), acks its buffers once
// drawn, and paints the mesh's colours (groups over the heat map). Owns no state of its own: the
// positions and heat values it writes are the session's.
import { Code } from "@connectrpc/connect";
import type { HeatMetric, ToWorker, UpdateInfo } from "../frames";
import type { DragToFrame } from "../frame_latency";
import type { Interaction } from "../interaction";
import type { Viewer3D } from "../scene";
import type { Hooks, PageMetrics } from "../test_hooks";
import type { ColorPainter } from "../ui/colors";
import type { Banner } from "../ui/dom";
import { showBytes, showResult } from "../ui/metrics";
import { COARSE, ENCODING, LINK_SIZED } from "./config";
import type { Session } from "./session";
import { openWatch, type Frame } from "./watch_stream";

/** What the frames need from the page. */
export interface FramesHost {
  readonly banner: Banner;
  readonly hooks: Hooks;
  readonly metrics: PageMetrics;
  readonly dragToFrame: DragToFrame;
  /** The open session (a stream's events for any other are dropped). */
  session(): Session | null;
  viewer(): Viewer3D;
  interaction(): Interaction;
  colors(): ColorPainter;
  modalActive(): boolean;
  /** A move is in flight (the target dots stay until it is answered). */
  moveInFlight(): boolean;
  heatMetric(): HeatMetric | null;
  heatMax(metric: HeatMetric): number;
  /** The session is gone (its stream ended or answered NOT_FOUND). */
  markGone(s: Session, detail?: string): void;
  placeGizmo(): void;
}

export class FramesView {
  constructor(private readonly host: FramesHost) {}

  startStream(s: Session, indices: Uint32Array): void {
    const h = this.host;
    // Events of a stream that is no longer the page's (closed, switched, gone) are dropped.
    const current = () => h.session() === s && !s.gone;
    s.worker = openWatch({
      type: "open", origin: location.origin, sessionId: s.creds.sessionId, token: s.creds.token, encoding: ENCODING, updates: LINK_SIZED, coarse: COARSE && s.role === "edit", vertexCount: s.state.vertexCount,
      indices: Uint32Array.from(indices), rest: Float32Array.from(s.rest), heat: h.heatMetric(), pageTimeOrigin: performance.timeOrigin,
    }, {
      frame: (f) => { if (current()) this.onFrame(s, f); },
      status: (text) => { if (current()) h.banner.status(text); },
      bad: (message) => { if (current()) h.banner.error("Bad update from the server", new Error(message)); },
      ended: () => {
        if (!current()) return;
        s.resolveSnapshot();
        h.markGone(s, "The session was closed by its owner (or an operator). Its link no longer opens it.");
      },
      failed: (e) => {
        if (!current()) return;
        s.resolveSnapshot();
        if (e.code === Code.NotFound) h.markGone(s);
        else {
          h.banner.error("Watching the session failed", e, "watch");
          h.hooks.ready = false;
        }
      },
      workerFailed: (message) => h.banner.error("The viewer's update worker failed", new Error(message)),
    });
  }

  /** A drag, gizmo drag or modal transform is under way. */
  private gesturing(): boolean {
    return this.host.interaction().dragging || this.host.viewer().gizmo.dragging || this.host.modalActive();
  }

  /** The gesture ended: the full mesh again, if its coarse level was drawn. */
  endCoarse(): void {
    const p = this.host.session()?.state.positions;
    const viewer = this.host.viewer();
    if (p && viewer.coarsePending) viewer.showFull(p);
  }

  /** A frame from the worker: the newest positions (with the updates since the last frame). */
  private onFrame(s: Session, f: Frame): void {
    const h = this.host;
    const viewer = h.viewer();
    const metrics = h.metrics;
    const last = f.updates[f.updates.length - 1] as UpdateInfo | undefined;
    for (const u of f.updates) {
      metrics.updateBytes.push(u.bytes);
      metrics.updateEncodings.push(u.encoding);
    }
    metrics.updatesDropped += Math.max(0, f.updates.length - 1);
    metrics.workerMs.push(f.workMs);
    s.state.positions.set(f.positions);
    s.state.revision = f.revision;
    // Kept (Auto, recolouring): a copy, the frame's own buffer goes back to the worker.
    s.heat = f.heat ? (s.heat && s.heat.length === f.heat.length ? s.heat : new Float32Array(f.heat.length)) : null;
    if (s.heat && f.heat) s.heat.set(f.heat);
    s.heatMetric = f.heatMetric;
    // During a drag of a multiresolution session: the coarse level the move solved on (a
    // fraction of the vertices to upload and draw); the full mesh otherwise and after release.
    if (!(f.coarse && viewer.setCoarseFrame(f.coarse, this.gesturing()))) {
      viewer.setFrame(f.positions, f.normals, f.sphere);
    }
    if (last) {
      showBytes(last.bytes, last.encoding);
      showResult({
        revision: BigInt(last.revision), eTheta: last.eTheta, ePhi: last.ePhi, areaLogRms: last.areaLogRms, iterations: last.iterations,
        pcgIterations: last.pcgIterations, solveSeconds: last.solveSeconds, converged: last.converged,
      }, f.revision, this.gesturing());
    }
    if (h.heatMetric()) this.recolor(); // group colours do not change with the positions
    h.hooks.revision = f.revision;
    metrics.updatesRendered++;
    const rendered = performance.now();
    metrics.renderedAt.push(rendered);
    metrics.renderedRefinement.push(!!last?.refinement);
    metrics.renderedConverged.push(!!last?.converged);
    if (!h.moveInFlight()) viewer.setTargets(null);
    s.resolveSnapshot();
    if (!viewer.gizmo.dragging) h.placeGizmo();
    const rev = f.revision;
    viewer.onNextFrame(() => {
      h.dragToFrame.drawn(rev, performance.now());
      // The frame is drawn: the worker may fill its buffers again (the newest update next).
      if (s.worker && h.session() === s) {
        const ack: ToWorker = { type: "ack", positions: f.positions, normals: f.normals, heat: f.heat };
        s.worker.postMessage(ack, [f.positions.buffer, f.normals.buffer, ...(f.heat ? [f.heat.buffer] : [])]);
      }
    });
  }

  /** Group colours over everything, then the heat map (fixed scale) or the base colours. */
  recolor(): void {
    const s = this.host.session();
    if (!s) return;
    const metric = this.host.heatMetric();
    const heat = metric && s.heat && s.heatMetric === metric ? s.heat : null;
    this.host.colors().paint(s.draft, s.selection.magnify, heat, metric ? this.host.heatMax(metric) : 1);
  }
}
