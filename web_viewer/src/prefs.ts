import { DEFAULT_HEAT_SCALE, parseScale } from "./heatscale";

// View preferences that belong to the person, not the session (a watcher's heat-map mode is not
// the editor's): kept in the browser's localStorage and restored on every page load.

export interface ViewPrefs {
  heatmap: boolean;
  heatmapMode: "angle" | "area";
  wireframe: boolean;
  ghost: boolean;
  /** The heat map's fixed scale tops (src/heatscale.ts): degrees, and an area ratio. */
  heatScaleAngle: number;
  heatScaleArea: number;
}

export const DEFAULT_PREFS: ViewPrefs = {
  heatmap: false, heatmapMode: "angle", wireframe: false, ghost: false,
  heatScaleAngle: DEFAULT_HEAT_SCALE.angleDeg, heatScaleArea: DEFAULT_HEAT_SCALE.areaRatio,
};
const KEY = "meshdeform.viewPrefs.v1";

/** The stored preferences; defaults for anything missing, malformed or unreadable. */
export function loadPrefs(storage: Pick<Storage, "getItem"> | null): ViewPrefs {
  let raw: unknown = null;
  try {
    raw = JSON.parse(storage?.getItem(KEY) ?? "null");
  } catch {
    raw = null;
  }
  const o = (raw && typeof raw === "object" ? raw : {}) as Record<string, unknown>;
  const bool = (k: keyof ViewPrefs) => (typeof o[k] === "boolean" ? (o[k] as boolean) : (DEFAULT_PREFS[k] as boolean));
  return {
    heatmap: bool("heatmap"),
    heatmapMode: o.heatmapMode === "area" || o.heatmapMode === "angle" ? o.heatmapMode : DEFAULT_PREFS.heatmapMode,
    wireframe: bool("wireframe"),
    ghost: bool("ghost"),
    heatScaleAngle: parseScale("angle", String(o.heatScaleAngle ?? "")).ok ? Number(o.heatScaleAngle) : DEFAULT_PREFS.heatScaleAngle,
    heatScaleArea: parseScale("area", String(o.heatScaleArea ?? "")).ok ? Number(o.heatScaleArea) : DEFAULT_PREFS.heatScaleArea,
  };
}

/** Stores the preferences (a full or private-mode storage is ignored: they are a convenience). */
export function savePrefs(storage: Pick<Storage, "setItem"> | null, prefs: ViewPrefs): void {
  try {
    storage?.setItem(KEY, JSON.stringify(prefs));
  } catch {
    /* quota or disabled storage */
  }
}
