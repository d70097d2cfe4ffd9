// The heat map's colour scale (issue 44): fixed per metric and set by the user (in degrees for
// angles, as an area ratio for area), so that colours mean the same from one update to the next;
// "Auto" sets it once from what is on screen, on request. Values past the top are drawn in the
// top colour, and the legend says so. Pure.

export type HeatMetric = "angle" | "area";

/** The top of each metric's scale: degrees of mean |Δ corner angle|, and an area ratio (>= 1:
 * ×r grown or ÷r shrunk). */
export interface HeatScale {
  angleDeg: number;
  areaRatio: number;
}

export const DEFAULT_HEAT_SCALE: HeatScale = { angleDeg: 5, areaRatio: 1.25 };

/** The top of the scale in the map's own units: radians, or |log(area ratio)|. */
export function heatMax(metric: HeatMetric, s: HeatScale): number {
  return metric === "angle" ? (s.angleDeg * Math.PI) / 180 : Math.log(s.areaRatio);
}

/** The value shown in the scale field for a metric. */
export function scaleValue(metric: HeatMetric, s: HeatScale): number {
  return metric === "angle" ? s.angleDeg : s.areaRatio;
}

export type ParsedScale = { ok: true; value: number } | { ok: false; reason: string };

/** A typed scale top: degrees in (0, 180], or an area ratio in (1, 100]. */
export function parseScale(metric: HeatMetric, text: string): ParsedScale {
  const v = Number(text.trim());
  if (text.trim() === "" || !Number.isFinite(v)) return { ok: false, reason: "Type a number." };
  if (metric === "angle") {
    return v > 0 && v <= 180 ? { ok: true, value: v } : { ok: false, reason: "Angles: more than 0° and at most 180°." };
  }
  return v > 1 && v <= 100 ? { ok: true, value: v } : { ok: false, reason: "Area: a ratio above 1 (×1.25 means 25% grown or shrunk), at most 100." };
}

export function withScale(s: HeatScale, metric: HeatMetric, value: number): HeatScale {
  return metric === "angle" ? { ...s, angleDeg: value } : { ...s, areaRatio: value };
}

/** Two significant digits, rounded up (a scale that covers the values). */
function roundUp2(x: number): number {
  if (!(x > 0)) return x;
  const p = Math.pow(10, Math.floor(Math.log10(x)) - 1);
  return Math.ceil(x / p - 1e-9) * p;
}

/** "Auto": the scale top that covers 98% of the vertices now (`values` in the map's units:
 * radians or |log ratio|), in the field's units, rounded up to two digits; at least a floor. */
export function autoScale(metric: HeatMetric, values: ArrayLike<number>): number {
  const s = Float32Array.from(values).sort();
  const q = s.length ? s[Math.min(s.length - 1, Math.floor(s.length * 0.98))] : 0;
  if (metric === "angle") return Math.max(0.1, roundUp2((q * 180) / Math.PI));
  return Math.max(1.01, 1 + roundUp2(Math.exp(q) - 1));
}

/** Legend: labels at 0, half and the top (the top marked "or more"), and what is measured. */
export function legend(metric: HeatMetric, s: HeatScale): { ticks: [string, string, string]; what: string } {
  const fmt = (x: number) => (x >= 10 ? x.toFixed(0) : x >= 1 ? x.toFixed(1) : x.toPrecision(2));
  if (metric === "angle") {
    return { ticks: ["0°", `${fmt(s.angleDeg / 2)}°`, `≥ ${fmt(s.angleDeg)}°`], what: "mean |Δ corner angle| against the rest mesh" };
  }
  const half = Math.exp(Math.log(s.areaRatio) / 2);
  return {
    ticks: ["×1", `×${half.toFixed(2)}`, `≥ ×${s.areaRatio.toFixed(2)} or ÷${s.areaRatio.toFixed(2)}`],
    what: "face area against the rest mesh (grown ×, shrunk ÷)",
  };
}
