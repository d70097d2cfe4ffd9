import { describe, expect, it } from "vitest";
import { DEFAULT_PREFS, loadPrefs, savePrefs } from "../src/prefs";

function memory() {
  const m = new Map<string, string>();
  return { getItem: (k: string) => m.get(k) ?? null, setItem: (k: string, v: string) => void m.set(k, v) };
}

describe("view preferences", () => {
  it("round-trip through storage", () => {
    const s = memory();
    const p = { heatmap: true, heatmapMode: "area" as const, wireframe: true, ghost: false, heatScaleAngle: 2.5, heatScaleArea: 1.1 };
    savePrefs(s, p);
    expect(loadPrefs(s)).toEqual(p);
  });
  it("keep only valid heat map scales", () => {
    const s = memory();
    s.setItem("meshdeform.viewPrefs.v1", JSON.stringify({ heatScaleAngle: -3, heatScaleArea: 0.5 }));
    expect(loadPrefs(s)).toEqual(DEFAULT_PREFS);
    s.setItem("meshdeform.viewPrefs.v1", JSON.stringify({ heatScaleAngle: 12, heatScaleArea: 2 }));
    expect(loadPrefs(s)).toMatchObject({ heatScaleAngle: 12, heatScaleArea: 2 });
  });
  it("fall back to the defaults for missing, malformed or foreign values", () => {
    expect(loadPrefs(null)).toEqual(DEFAULT_PREFS);
    const s = memory();
    s.setItem("meshdeform.viewPrefs.v1", "{not json");
    expect(loadPrefs(s)).toEqual(DEFAULT_PREFS);
    s.setItem("meshdeform.viewPrefs.v1", JSON.stringify({ heatmap: "yes", heatmapMode: "curvature", ghost: true }));
    expect(loadPrefs(s)).toEqual({ ...DEFAULT_PREFS, ghost: true });
  });
  it("ignore a storage that throws", () => {
    expect(() => savePrefs({ setItem: () => { throw new Error("quota"); } }, DEFAULT_PREFS)).not.toThrow();
    expect(loadPrefs({ getItem: () => { throw new Error("denied"); } })).toEqual(DEFAULT_PREFS);
  });
});
