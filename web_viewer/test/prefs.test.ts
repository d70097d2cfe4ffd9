import { describe, expect, it } from "vitest";
import { DEFAULT_PREFS, loadPrefs, savePrefs } from "../src/prefs";

function memory() {
  const m = new Map<string, string>();
  return { getItem: (k: string) => m.get(k) ?? null, setItem: (k: string, v: string) => void m.set(k, v) };
}

describe("view preferences", () => {
  it("round-trip through storage", () => {
    const s = memory();
    savePrefs(s, { heatmap: true, heatmapMode: "area", wireframe: true, ghost: false });
    expect(loadPrefs(s)).toEqual({ heatmap: true, heatmapMode: "area", wireframe: true, ghost: false });
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
