// The mesh's vertex colours: every group in its colour (the selected one lighter) drawn over the
// heat map (issue 44: the map no longer hides the handle and fixed regions), the heat map on a
// fixed scale (src/heatscale.ts) elsewhere, else the magnify region and the free vertices. Filled
// straight into the colour buffer from linear look-up tables: on a 187k-vertex mesh it runs on
// every frame of a drag with the map on.
import { groupColor, type GroupSet } from "../groups";
import { ramp } from "../distortion";
import { srgbToLinear, type Viewer3D } from "../scene";

const BASE: [number, number, number] = [0.78, 0.8, 0.84];
const MAGNIFY: [number, number, number] = [0.25, 0.68, 0.42];
const STEPS = 256;

const lin = (c: readonly number[]) => c.map(srgbToLinear) as [number, number, number];

export class ColorPainter {
  private readonly heatLut = new Float32Array(STEPS * 3);
  private last: { draft: GroupSet; magnify: Uint8Array; heat: Float32Array | null; max: number } | null = null;

  constructor(private readonly viewer: Viewer3D) {
    for (let i = 0; i < STEPS; i++) this.heatLut.set(lin(ramp(i / (STEPS - 1))), i * 3);
  }

  private palette(draft: GroupSet): [number, number, number][] {
    return Array.from({ length: draft.size }, (_, k) => {
      const c = groupColor(draft.role(k), draft.ordinal(k));
      return (k === draft.selected ? c.map((x) => x + (1 - x) * 0.4) : c) as [number, number, number];
    });
  }

  /** `heat`: per-vertex values in the map's units, `max` the top of the scale; null: no map. */
  paint(draft: GroupSet, magnify: Uint8Array, heat: Float32Array | null, max: number): void {
    this.last = { draft, magnify, heat, max };
    const out = this.viewer.colorArray();
    if (!out) return;
    const pal = this.palette(draft).map(lin);
    const base = lin(BASE), mag = lin(MAGNIFY);
    const n = Math.min(out.length / 3, draft.vertexCount);
    const scale = (STEPS - 1) / Math.max(max, 1e-12);
    for (let v = 0; v < n; v++) {
      const k = draft.groupOf(v);
      const o = v * 3;
      if (k >= 0) {
        const c = pal[k];
        out[o] = c[0]; out[o + 1] = c[1]; out[o + 2] = c[2];
      } else if (heat) {
        const x = heat[v] * scale;
        const i = (x >= STEPS - 1 || !(x >= 0) ? (x >= STEPS - 1 ? STEPS - 1 : 0) : Math.round(x)) * 3;
        out[o] = this.heatLut[i]; out[o + 1] = this.heatLut[i + 1]; out[o + 2] = this.heatLut[i + 2];
      } else {
        const c = magnify[v] ? mag : base;
        out[o] = c[0]; out[o + 1] = c[1]; out[o + 2] = c[2];
      }
    }
    this.viewer.colorsChanged();
  }

  /** The sRGB colour vertex v was last painted (tests read what the map shows). */
  srgbOf(v: number): number[] {
    const l = this.last;
    if (!l || v < 0 || v >= l.draft.vertexCount) return [];
    const k = l.draft.groupOf(v);
    if (k >= 0) return [...this.palette(l.draft)[k]];
    if (l.heat) {
      const x = l.heat[v] / Math.max(l.max, 1e-12);
      return [...ramp(Math.round(Math.min(1, Math.max(0, x)) * (STEPS - 1)) / (STEPS - 1))];
    }
    return [...(l.magnify[v] ? MAGNIFY : BASE)];
  }
}
