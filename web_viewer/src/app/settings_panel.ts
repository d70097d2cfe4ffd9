// The settings panel: the solver's controls (method, ORA, scale control, iterations, magnify
// scale), the request fields and the history entry's settings they make, and the view controls
// kept in this browser (heat map, its scale and legend, wireframe, rest-pose ghost). Owns the
// iterations in use (the field may hold a bad value meanwhile) and the heat map's scale; the
// magnify region itself is the session's.
import { create } from "@bufbuild/protobuf";
import { MagnifyRegionSchema, Method, type MoveHandlesRequest } from "../gen/meshdeform/v1/deformation_pb";
import type { HeatMetric, ToWorker } from "../frames";
import { autoScale, DEFAULT_HEAT_SCALE, heatMax, legend, parseScale, scaleValue, withScale, type HeatScale } from "../heatscale";
import { DEFAULT_ITERATIONS, parseIterations } from "../iterations";
import { loadPrefs, savePrefs } from "../prefs";
import { rigidityLabel, rigidityStep, rigidityValue } from "../rigidity";
import type { Viewer3D } from "../scene";
import type { SettingsView } from "../edit_state";
import type { Settings } from "../timeline";
import { $, $in, $sel } from "../ui/dom";
import { ENCODING, storage, UPDATES } from "./config";
import type { Session } from "./session";

/** What the panel needs from the page. */
export interface SettingsHost {
  session(): Session | null;
  viewer(): Viewer3D;
  /** A solver setting changed: solve again with it (a step of the history). */
  resolve(): void;
  /** The heat map's metric or scale changed: paint the colours again. */
  recolor(): void;
  /** A sentence in the error banner. */
  message(text: string): void;
}

/** The request fields the controls set on a MoveHandles. */
export type SettingsRequest = Pick<MoveHandlesRequest, "method" | "ora" | "rigidity" | "maxIterations" | "magnify" | "encoding" | "omitPositions" | "editor">;

export class SettingsPanel {
  private iterationsValue = DEFAULT_ITERATIONS;
  private heatScale: HeatScale = { ...DEFAULT_HEAT_SCALE };

  constructor(private readonly host: SettingsHost) {}

  method(): Method {
    return Number($sel("method").value) as Method;
  }

  /** What makes two move targets' settings differ (the coalescer's key). */
  optsKey(): string {
    return [$sel("method").value, $in("ora").checked, this.rigidity(), this.iterationsValue, $in("magnify").value, this.host.session()?.selection.magnifyIndices().length ?? 0].join("|");
  }

  private rigidity(): number {
    return rigidityValue(Number($in("rigidity").value));
  }

  /** The solver settings the controls show (a history entry's). */
  currentSettings(): Settings {
    return {
      method: this.method(), ora: $in("ora").checked, rigidityStep: Number($in("rigidity").value), iterations: this.iterationsValue,
      magnifyScale: Number($in("magnify").value), magnify: this.host.session()?.selection.magnifyIndices() ?? [],
    };
  }

  /** An opened session's settings (those of its last move; null: it has none, the controls keep
   * the user's choices) and scale control (`rigidity`, the session's when it has no settings). */
  showOpened(settings: SettingsView | null, rigidity: number): void {
    $in("rigidity").value = String(rigidityStep(settings?.rigidity ?? rigidity));
    if (settings) {
      $sel("method").value = String(settings.method);
      $in("ora").checked = settings.ora;
      $in("iterations").value = String(settings.iterations);
      this.iterationsValue = settings.iterations;
      $in("magnify").value = String(settings.magnifyScale);
      $("magnify-val").textContent = settings.magnifyScale.toFixed(2);
    }
  }

  /** Shows `st` in the controls (an undo or redo to a step solved with them). */
  applySettings(st: Settings): void {
    const s = this.host.session();
    $sel("method").value = String(st.method);
    $in("ora").checked = st.ora;
    $in("rigidity").value = String(st.rigidityStep);
    $in("iterations").value = String(st.iterations);
    this.iterationsValue = st.iterations;
    this.checkIterations();
    $in("magnify").value = String(st.magnifyScale);
    $("magnify-val").textContent = st.magnifyScale.toFixed(2);
    if (s) {
      s.selection.clear();
      s.selection.paint(st.magnify, "magnify");
    }
    this.showRigidity();
    this.updateMethodAvailability();
  }

  showRigidity(): void {
    const session = this.host.session();
    $("rigidity-val").textContent = rigidityLabel(this.rigidity());
    // Only the scale-aware method has a scale term.
    $in("rigidity").disabled =
      this.method() !== Method.SCALE_AWARE || session?.role !== "edit" || !!session?.gone;
  }

  /** ARAP and Laplacian cannot magnify (the server refuses regions with them): while a magnify
   * region exists they are disabled, and while one of them is chosen the magnify mode is. */
  updateMethodAvailability(): void {
    const mag = !!this.host.session()?.selection.hasMagnify;
    const why = "Only the scale-aware method can magnify: erase the magnify region (Brush, mode erase) to use ARAP or Laplacian.";
    for (const opt of Array.from($sel("method").options)) {
      if (opt.value === String(Method.SCALE_AWARE)) continue;
      opt.disabled = mag;
      opt.title = mag ? why : "";
    }
    $sel("method").title = mag ? why : "";
    $("method-note").textContent = mag ? "ARAP and Laplacian are off while a magnify region exists (only scale-aware can magnify)." : "";
    $("method-note").hidden = !mag;
    const scaleAware = this.method() === Method.SCALE_AWARE;
    const magOpt = Array.from($sel("paint-mode").options).find((o) => o.value === "magnify")!;
    magOpt.disabled = !scaleAware;
    magOpt.title = scaleAware ? "" : "Magnify regions need the scale-aware method.";
    if (!scaleAware && $sel("paint-mode").value === "magnify") $sel("paint-mode").value = "handle";
  }

  /** Validates the iterations field as typed; a bad value is shown and not used. */
  private checkIterations(): boolean {
    const r = parseIterations($in("iterations").value);
    $in("iterations").classList.toggle("invalid", !r.ok);
    $in("iterations").setCustomValidity(r.ok ? "" : r.reason);
    $("iterations-note").textContent = r.ok ? "" : `${r.reason} Moves keep using ${this.iterationsValue}.`;
    $("iterations-note").hidden = r.ok;
    if (r.ok) this.iterationsValue = r.value;
    return r.ok;
  }

  /** The request fields for the controls' settings. */
  request(): SettingsRequest {
    const mag = this.host.session()?.selection.magnifyIndices() ?? [];
    return {
      method: this.method(), ora: $in("ora").checked, rigidity: this.rigidity(), maxIterations: this.iterationsValue, encoding: ENCODING,
      omitPositions: UPDATES !== undefined, // link-sized updates (issue 45): geometry comes from Watch only
      editor: "web-viewer",
      magnify: mag.length ? [create(MagnifyRegionSchema, { vertices: mag, scale: Number($in("magnify").value) })] : [],
    };
  }

  heatMode(): HeatMetric {
    return $sel("heatmap-mode").value === "area" ? "area" : "angle";
  }

  /** The heat map's metric, null while it is off. */
  heatMetric(): HeatMetric | null {
    return $in("heatmap").checked ? this.heatMode() : null;
  }

  /** The value at the top of the heat map's colour scale for `metric`. */
  heatMax(metric: HeatMetric): number {
    return heatMax(metric, this.heatScale);
  }

  private showHeatScale(): void {
    const metric = this.heatMode();
    $in("heat-scale").value = String(scaleValue(metric, this.heatScale));
    $("heat-scale-unit").textContent = metric === "angle" ? "°" : "× area";
    const l = legend(metric, this.heatScale);
    $("legend-min").textContent = l.ticks[0];
    $("legend-mid").textContent = l.ticks[1];
    $("legend-max").textContent = l.ticks[2];
    $("legend-what").textContent = l.what;
    $("legend").hidden = !$in("heatmap").checked;
    $("heat-scale-row").hidden = !$in("heatmap").checked;
  }

  /** Wires the panel's controls and shows this browser's view preferences. */
  wire(): void {
    const h = this.host;
    $in("iterations").addEventListener("input", () => this.checkIterations());
    $in("iterations").addEventListener("change", () => {
      if (this.checkIterations()) h.resolve();
    });
    for (const id of ["method", "ora"]) $(id).addEventListener("change", () => h.resolve());
    $in("rigidity").addEventListener("input", () => this.showRigidity());
    $in("rigidity").addEventListener("change", () => h.resolve());  // re-solves live
    $sel("method").addEventListener("change", () => {
      this.showRigidity();
      this.updateMethodAvailability();
    });
    $in("magnify").addEventListener("input", () => ($("magnify-val").textContent = Number($in("magnify").value).toFixed(2)));
    $in("magnify").addEventListener("change", () => {
      const session = h.session();
      if (session && !session.selection.hasMagnify) h.message("Paint a “magnify region” first (Brush or Lasso, mode magnify region).");
      h.resolve();
    });
    // View preferences are the person's, not the session's: kept in this browser.
    const prefs = loadPrefs(storage());
    $in("heatmap").checked = prefs.heatmap;
    $sel("heatmap-mode").value = prefs.heatmapMode;
    $in("wireframe").checked = prefs.wireframe;
    $in("ghost-rest").checked = prefs.ghost;
    this.heatScale = { angleDeg: prefs.heatScaleAngle, areaRatio: prefs.heatScaleArea };
    h.viewer().setWireframe(prefs.wireframe);
    const keepPrefs = () => savePrefs(storage(), {
      heatmap: $in("heatmap").checked, heatmapMode: $sel("heatmap-mode").value === "area" ? "area" : "angle",
      wireframe: $in("wireframe").checked, ghost: $in("ghost-rest").checked,
      heatScaleAngle: this.heatScale.angleDeg, heatScaleArea: this.heatScale.areaRatio,
    });
    for (const id of ["heatmap", "heatmap-mode", "wireframe", "ghost-rest"]) $(id).addEventListener("change", keepPrefs);
    const heatChanged = () => {
      this.showHeatScale();
      h.session()?.worker?.postMessage({ type: "heat", metric: this.heatMetric() } satisfies ToWorker);
      h.recolor();
    };
    $in("heatmap").addEventListener("change", heatChanged);
    $sel("heatmap-mode").addEventListener("change", heatChanged);
    $in("heat-scale").addEventListener("change", () => {
      const metric = this.heatMode();
      const r = parseScale(metric, $in("heat-scale").value);
      $in("heat-scale").classList.toggle("invalid", !r.ok);
      $("heat-scale-note").textContent = r.ok ? "" : `${r.reason} The map keeps its scale.`;
      $("heat-scale-note").hidden = r.ok;
      if (!r.ok) return;
      this.heatScale = withScale(this.heatScale, metric, r.value);
      keepPrefs();
      this.showHeatScale();
      h.recolor();
    });
    $("heat-auto").addEventListener("click", () => {
      const s = h.session();
      const metric = this.heatMode();
      if (!s?.heat || s.heatMetric !== metric) return;
      this.heatScale = withScale(this.heatScale, metric, autoScale(metric, s.heat));
      keepPrefs();
      this.showHeatScale();
      h.recolor();
    });
    this.showHeatScale();
    $in("wireframe").addEventListener("change", () => h.viewer().setWireframe($in("wireframe").checked));
    $in("ghost-rest").addEventListener("change", () => h.viewer().setGhost($in("ghost-rest").checked, h.session()?.rest ?? null));
  }
}
