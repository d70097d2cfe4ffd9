// A session's settings and undo history as the server keeps them (SessionInfo.edit, issue 17),
// turned into what the viewer shows: the controls' values, every handle group's move state and
// the undo stack. Pure functions: the state logic is tested without a browser.
import { Method, type EditSettings, type EditState, type EditStep } from "./gen/meshdeform/v1/deformation_pb";
import { cloneMove, IDENTITY, rotate, type GroupStates, type MoveState, type Vec3 } from "./moves";
import { DEFAULT_ITERATIONS } from "./iterations";
import { rigidityStep } from "./rigidity";
import type { Entry, Settings } from "./timeline";

/** What the settings controls show for the session. */
export interface SettingsView {
  method: Method;
  ora: boolean;
  iterations: number;
  rigidity: number | null; // null: the session's default (no move yet)
  magnifyScale: number;
  magnifyVertices: number[];
}

/** The controls' values for `settings` (the last move's); defaults before the first move. */
export function settingsView(settings: EditSettings | undefined): SettingsView {
  if (!settings) {
    return { method: Method.SCALE_AWARE, ora: false, iterations: DEFAULT_ITERATIONS, rigidity: null, magnifyScale: 1, magnifyVertices: [] };
  }
  const region = settings.magnify[settings.magnify.length - 1];
  return {
    method: settings.method === Method.UNSPECIFIED ? Method.SCALE_AWARE : settings.method,
    ora: settings.ora,
    iterations: settings.maxIterations > 0 ? settings.maxIterations : DEFAULT_ITERATIONS,
    rigidity: settings.rigidity,
    magnifyScale: region && region.scale > 0 ? region.scale : 1,
    // The viewer paints one region; a session edited elsewhere may have several: their union.
    magnifyVertices: [...new Set(settings.magnify.flatMap((r) => r.vertices))].sort((a, b) => a - b),
  };
}

/**
 * Every group's state in `step` (identity for groups without a move), as the viewer keeps them:
 * about the group's anchor centroid. A move about another pivot p is re-expressed about the
 * centroid c with the same targets: p + sR(a - p) + t = c + sR(a - c) + t' with
 * t' = t + (p - c) - sR(p - c).
 */
export function statesFromStep(step: EditStep | undefined, centroids: (Vec3 | null)[]): GroupStates {
  const states: GroupStates = centroids.map(() => cloneMove(IDENTITY));
  for (const m of step?.moves ?? []) {
    if (m.group >= states.length) continue;
    const q = m.rotation ? [m.rotation.w, m.rotation.x, m.rotation.y, m.rotation.z] : [1, 0, 0, 0];
    const n = Math.hypot(q[0], q[1], q[2], q[3]) || 1;
    const rotation = [q[0] / n, q[1] / n, q[2] / n, q[3] / n] as MoveState["rotation"];
    const scale = m.scale ?? 1;
    let t: Vec3 = [m.translation?.x ?? 0, m.translation?.y ?? 0, m.translation?.z ?? 0];
    const c = centroids[m.group];
    if (m.pivot && c) {
      const d: Vec3 = [m.pivot.x - c[0], m.pivot.y - c[1], m.pivot.z - c[2]];
      const r = rotate(rotation, d);
      t = [t[0] + d[0] - scale * r[0], t[1] + d[1] - scale * r[1], t[2] + d[2] - scale * r[2]];
    }
    states[m.group] = { translation: t, rotation, scale };
  }
  return states;
}

/** The undo stack's states and current index for the server's history. */
export function historyFromEdit(edit: EditState | undefined, centroids: (Vec3 | null)[]): { states: GroupStates[]; index: number } {
  const steps = edit?.steps.length ? edit.steps : [undefined];
  const states = steps.map((s) => statesFromStep(s, centroids));
  const index = Math.min(Math.max(0, edit?.position ?? 0), states.length - 1);
  return { states, index };
}

/** A fresh gesture id for one drag (MoveHandlesRequest.gesture): random, non-zero, 53 bits. */
export function newGesture(random: () => number = Math.random): bigint {
  return BigInt(Math.floor(random() * (2 ** 53 - 1))) + 1n;
}

/** A step's settings as the page keeps them (timeline.ts), `fallback` when it has none. */
export function stepSettings(settings: EditSettings | undefined, fallback: Settings, vertexCount: number): Settings {
  if (!settings) return fallback;
  const v = settingsView(settings);
  return {
    method: v.method, ora: v.ora, rigidityStep: rigidityStep(v.rigidity ?? 0), iterations: v.iterations, magnifyScale: v.magnifyScale,
    magnify: v.magnifyVertices.filter((x) => x < vertexCount),
  };
}

/** The page's history entries for the server's (one epoch, `epoch` filled in by the caller):
 * every step's states, settings (the step's own, else `fallback`) and the revision the server
 * keeps for it. */
export function entriesFromEdit(edit: EditState | undefined, centroids: (Vec3 | null)[],
  fallback: (index: number, step: EditStep | undefined) => Settings, vertexCount: number): { entries: Entry[]; index: number } {
  const { states, index } = historyFromEdit(edit, centroids);
  const steps = edit?.steps ?? [];
  const entries = states.map((st, i): Entry => ({
    epoch: 0, serverPos: i, states: st, draft: null,
    settings: stepSettings(steps[i]?.settings, fallback(i, steps[i]), vertexCount),
    revision: steps[i]?.revision === undefined ? null : Number(steps[i].revision),
  }));
  return { entries, index };
}
