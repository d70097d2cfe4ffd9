// The metrics panel.
import type { DeformResult } from "../gen/meshdeform/v1/deformation_pb";
import { $ } from "./dom";

const fmt = (x: number, d = 4) => (Number.isFinite(x) ? x.toFixed(d) : "–");

/** `dragging`: a drag is under way, so "refining…" (the server resting between drags) is not shown. */
export type ResultSummary = Pick<DeformResult, "revision" | "eTheta" | "ePhi" | "areaLogRms" | "iterations" | "pcgIterations" | "solveSeconds" | "converged">;

export function showResult(r: ResultSummary, shownRevision: number, dragging = false): void {
  $("metric-etheta").textContent = fmt(r.eTheta, 5);
  $("metric-ephi").textContent = fmt(r.ePhi, 5);
  $("metric-area").textContent = fmt(r.areaLogRms, 5);
  $("metric-iters").textContent = String(r.iterations);
  $("metric-pcg").textContent = String(r.pcgIterations);
  $("metric-solve-ms").textContent = fmt(r.solveSeconds * 1000, 1);
  $("metric-revision").textContent = String(shownRevision);
  // Not converged: the server keeps refining while the handles rest; if no revision follows
  // for a while its refinement budget ran out.
  const el = $("refine-hint");
  clearTimeout(idleTimer);
  if (Number(r.revision) === 0 || dragging) el.textContent = "";
  else if (r.converged) el.textContent = "converged";
  else {
    el.textContent = "refining…";
    idleTimer = setTimeout(() => (el.textContent = "resting (budget reached)"), 2500);
  }
}
let idleTimer: ReturnType<typeof setTimeout> | undefined;

export function showCounts(vertices: number, faces: number): void {
  $("metric-counts").textContent = `${vertices.toLocaleString("en")} / ${faces.toLocaleString("en")}`;
}

export function showBytes(bytes: number, encoding: string): void {
  const s = bytes >= 1 << 20 ? `${(bytes / (1 << 20)).toFixed(2)} MiB` : bytes >= 1024 ? `${(bytes / 1024).toFixed(1)} KiB` : `${bytes} B`;
  $("metric-bytes").textContent = `${s} (${encoding})`;
}
