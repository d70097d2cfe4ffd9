// The page's test hooks (window.__meshdeform): what the Chromium tests (tests/viewer/) and the
// browser bench (bench/viewer_latency.mjs) read and call, and the page's own measurements.
import * as THREE from "three";
import { HandleRole, type HandleGroup } from "./gen/meshdeform/v1/deformation_pb";
import type { GroupSpec } from "./groups";
import type { GroupStates } from "./moves";
import type { Tool } from "./interaction";
import { $ } from "./ui/dom";

export type Role = "edit" | "view";

export interface Hooks {
  ready: boolean;
  revision: number;
  sessionId: string;
  role: Role;
  vertexCount: number;
  lastError: string;
  /** True after the session turned out to be gone (NOT_FOUND) or the link could not be opened. */
  gone: boolean;
  /** Index of the selected group (into groups()), -1 for none. */
  selectedGroup: number;
  /** The open modal transform's overlay text ("" when none), and whether undo/redo is running. */
  modal: string;
  historyBusy: boolean;
  tool: Tool;
  /** Grab tool: the pointer is over the mesh (the radius preview shows). */
  hovering: boolean;
  /** Screen point of the selected handle group's centre (else the first handle group's). */
  handleScreenPoint(): { x: number; y: number } | null;
  /** Screen point of group i's centre as rendered, or of vertex v. */
  groupScreenPoint(i: number): { x: number; y: number } | null;
  vertexScreenPoint(v: number): { x: number; y: number } | null;
  worldScreenPoint(x: number, y: number, z: number): { x: number; y: number } | null;
  positions(): number[];
  /** The rest mesh (revision 0) as loaded. */
  restPositions(): number[];
  /** Per rendered frame and update: see metrics in App. inputDelayMs: per pointer event during a
   * drag, how long it waited before the page's handler ran. */
  metrics(): {
    dragToFrameMs: number[]; updateBytes: number[]; updateEncodings: string[]; updatesRendered: number; frameWorkMs: number[];
    renderedAt: number[]; renderedRefinement: boolean[]; renderedConverged: boolean[]; inputDelayMs: number[]; workerMs: number[];
    updatesDropped: number;
  };
  resetMetrics(): void;
  /** Every applied group's move as the page holds it (translation, rotation w x y z, scale). */
  moveStates(): { translation: number[]; rotation: number[]; scale: number }[];
  /** The session's handle groups as applied (role 'fixed' | 'handle'), for tests. */
  groups(): { role: "fixed" | "handle"; vertices: number[] }[];
  /** The painted groups (applied or not). */
  draftGroups(): { role: "fixed" | "handle"; vertices: number[] }[];
  /** The undo history: position and size. */
  history(): { position: number; size: number; canUndo: boolean; canRedo: boolean };
  /** The state notice shown (what is missing and the way out), "" for none. */
  notice(): string;
  /** The heat map's legend as shown, and the sRGB colour of vertex v on screen. */
  legend(): string[];
  vertexColor(v: number): number[];
  /** The view direction (unit, from the camera). */
  viewDirection(): number[];
  /** What is drawn: the coarse level of a multiresolution drag or the full mesh, and its vertex count. */
  drawn(): { coarse: boolean; vertices: number };
}

/** What the page measures per frame and update (Hooks.metrics). */
export interface PageMetrics {
  dragToFrameMs: number[];
  updateBytes: number[];
  updateEncodings: string[];
  updatesRendered: number;
  renderedAt: number[];
  renderedRefinement: boolean[];
  renderedConverged: boolean[];
  inputDelayMs: number[];
  workerMs: number[];
  updatesDropped: number;
}

export function newPageMetrics(): PageMetrics {
  return {
    dragToFrameMs: [], updateBytes: [], updateEncodings: [], updatesRendered: 0, renderedAt: [], renderedRefinement: [],
    renderedConverged: [], inputDelayMs: [], workerMs: [], updatesDropped: 0,
  };
}

type ScreenPoint = { x: number; y: number } | null;

/** What the hooks read of the page. */
export interface HookedApp {
  readonly session: {
    state: { positions: Float32Array };
    rest: Float32Array;
    groups: HandleGroup[];
    draft: { specs(): GroupSpec[] };
  } | null;
  readonly metrics: PageMetrics;
  readonly viewer: { frameWorkMs: number[]; viewDirection(): THREE.Vector3; readonly showingCoarse: boolean; drawnVertexCount(): number };
  readonly states: GroupStates;
  readonly timeline: { position: number; size: number; canUndo: boolean; canRedo: boolean };
  readonly noticeText: string;
  readonly colors: { srgbOf(v: number): number[] };
  hookHandlePoint(): ScreenPoint;
  hookGroupPoint(i: number): ScreenPoint;
  hookVertexPoint(v: number): ScreenPoint;
  screenPoint(c: THREE.Vector3 | null): ScreenPoint;
}

/** The hooks of `app`; the page sets their state fields (ready, revision, ...) as it goes. */
export function makeHooks(app: HookedApp): Hooks {
  return {
    ready: false,
    revision: -1,
    sessionId: "",
    role: "edit",
    vertexCount: 0,
    lastError: "",
    gone: false,
    selectedGroup: -1,
    modal: "",
    historyBusy: false,
    tool: "move",
    hovering: false,
    handleScreenPoint: () => app.hookHandlePoint(),
    groupScreenPoint: (i) => app.hookGroupPoint(i),
    vertexScreenPoint: (v) => app.hookVertexPoint(v),
    worldScreenPoint: (x, y, z) => app.screenPoint(new THREE.Vector3(x, y, z)),
    positions() {
      return Array.from(app.session?.state.positions ?? []);
    },
    restPositions() {
      return Array.from(app.session?.rest ?? []);
    },
    metrics() {
      const m = app.metrics;
      return {
        dragToFrameMs: [...m.dragToFrameMs], updateBytes: [...m.updateBytes], updateEncodings: [...m.updateEncodings], updatesRendered: m.updatesRendered,
        frameWorkMs: [...app.viewer.frameWorkMs], renderedAt: [...m.renderedAt], renderedRefinement: [...m.renderedRefinement],
        renderedConverged: [...m.renderedConverged], inputDelayMs: [...m.inputDelayMs], workerMs: [...m.workerMs], updatesDropped: m.updatesDropped,
      };
    },
    moveStates() {
      return app.states.map((m) => ({ translation: [...m.translation], rotation: [...m.rotation], scale: m.scale }));
    },
    groups() {
      return (app.session?.groups ?? []).map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" as const : "handle" as const, vertices: [...g.vertices] }));
    },
    draftGroups() {
      return app.session?.draft.specs().map((g) => ({ role: g.role, vertices: [...g.vertices] })) ?? [];
    },
    history() {
      return { position: app.timeline.position, size: app.timeline.size, canUndo: app.timeline.canUndo, canRedo: app.timeline.canRedo };
    },
    notice() {
      return app.noticeText;
    },
    legend() {
      return ["legend-min", "legend-mid", "legend-max", "legend-what"].map((id) => $(id).textContent ?? "");
    },
    vertexColor(v: number) {
      return app.colors.srgbOf(v);
    },
    viewDirection() {
      return app.viewer.viewDirection().toArray();
    },
    drawn() {
      return { coarse: app.viewer.showingCoarse, vertices: app.viewer.drawnVertexCount() };
    },
    resetMetrics() {
      const m = app.metrics;
      for (const a of [m.dragToFrameMs, m.updateBytes, m.updateEncodings, m.renderedAt, m.renderedRefinement, m.renderedConverged, m.inputDelayMs, m.workerMs]) a.length = 0;
      m.updatesRendered = 0;
      m.updatesDropped = 0;
      app.viewer.frameWorkMs.length = 0;
    },
  };
}
