// Moves: what the page sends through the coalescer (every handle group's move about its anchors,
// with the controls' settings) and the gestures that make them — a drag in the view plane, a
// pick-and-drag with Grab (its groups set while the pointer already moves), the gizmo on the
// selected handle group, a settings change solved again — each one step of the history; the
// gizmo's and markers' placement and the target dots of a slow solve. Owns the gesture under way
// and the pick whose handles are being set.
import * as THREE from "three";
import type { GroupMove, MoveHandlesResponse } from "../gen/meshdeform/v1/deformation_pb";
import { newGesture } from "../edit_state";
import type { Action } from "../errors";
import type { DragToFrame } from "../frame_latency";
import { groupColor, type GroupSpec } from "../groups";
import type { Interaction, PickHit, Tool } from "../interaction";
import { applyMove, cloneStates, pulledScale, toGroupMove, type GroupStates } from "../moves";
import { pickGroups } from "../pick";
import { derive, type Entry, type Settings } from "../timeline";
import { $, $in } from "../ui/dom";
import { dismissFirstHint } from "../ui/notice";
import { client } from "./config";
import type { PageState } from "./page";
import type { SettingsRequest } from "./settings_panel";
import type { MoveTarget, PendingPick, Session } from "./session";

/** What the moves need from the page. */
export interface MovesHost extends PageState {
  readonly dragToFrame: DragToFrame;
  interaction(): Interaction;
  modalActive(): boolean;
  tool(): Tool;
  /** The painted groups differ from the applied ones. */
  dirty(): boolean;
  historyBusy(): boolean;
  handleIndices(): number[];
  isHandle(i: number): boolean;
  selectedHandle(): number;
  appliedSpecs(): GroupSpec[];
  topology(s: Session): NonNullable<Session["topology"]>;
  setHandles(specs: GroupSpec[]): Promise<void>;
  selectGroup(i: number): void;
  fail(prefix: string, e: unknown, action: Action): void;
  optsKey(): string;
  currentSettings(): Settings;
  settingsRequest(): SettingsRequest;
  /** A move's server step, for the history. */
  answered(r: MoveHandlesResponse, t: MoveTarget | null): void;
  /** The gesture ended (the full mesh again if its coarse level was drawn). */
  endCoarse(): void;
  updateUndoButtons(): void;
  updateReady(): void;
  /** The mesh's size (its bounding box's diagonal). */
  meshScale(): number;
}

export class MovesController {
  private dragBase: GroupStates = [];
  private dragGroup = -1;
  private dragGesture = 0n;
  private dragEntry: Entry | null = null;
  private dragSent = false;
  private gizmoGesture = 0n;
  private pendingPick: PendingPick | null = null;
  private targetTimer: ReturnType<typeof setTimeout> | undefined;

  constructor(private readonly host: MovesHost) {}

  /** A pick's handles are being set (moves wait for them). */
  get picking(): boolean {
    return !!this.pendingPick;
  }

  /** The session closed: a pick under way is dropped. */
  clearPick(): void {
    this.pendingPick = null;
  }

  submitMove(states: GroupStates, t0: number, o: { force?: boolean; gesture?: bigint; entry?: Entry | null } = {}): void {
    const h = this.host;
    const s = h.session();
    if (!s || s.gone || h.handleIndices().length === 0 || s.role !== "edit") return;
    h.setStates(cloneStates(states));
    h.coalescer.submit({ states: cloneStates(states), t0, opts: h.optsKey(), gesture: o.gesture ?? 0n, entry: o.entry ?? null }, o.force ?? false);
    this.scheduleTargetGhost();
  }

  /** The moves of every handle group about the live anchors (moves are absolute). */
  groupMoves(states: GroupStates): GroupMove[] {
    const s = this.host.session()!;
    return this.host.handleIndices().map((i) => {
      const c = s.anchors[i]?.centroid ?? new THREE.Vector3();
      return toGroupMove(i, states[i], [c.x, c.y, c.z]);
    });
  }

  /** The coalescer's call for a target. */
  send(t: MoveTarget): Promise<MoveHandlesResponse> {
    const s = this.host.session()!;
    return client.moveHandles(
      { sessionId: s.creds.sessionId, token: s.creds.token, moves: this.groupMoves(t.states), gesture: t.gesture, ...this.host.settingsRequest() },
      { timeoutMs: 60_000 },
    );
  }

  /** A move's answer: its server step (for the history) and the latency bookkeeping. */
  onMoveResult(r: MoveHandlesResponse, t: MoveTarget | null): void {
    this.host.answered(r, t);
    const rev = Number(r.result?.revision ?? -1);
    if (rev < 0 || !t) return;
    // Geometry comes from Watch only (in order); the response is for flow control and latency.
    this.host.dragToFrame.answered(rev, t.t0, this.host.session()?.state.revision ?? -1);
  }

  /** A setting changed: solve again with it, as a step of the history (the server also keeps it
   * for the next page that opens the session). */
  resolveWithSettings(): void {
    const h = this.host;
    const cur = h.timeline.current;
    if (h.handleIndices().length === 0 || !cur || h.dirty()) return;
    const entry = derive(cur, { settings: h.currentSettings(), serverPos: -1, revision: null, draft: null });
    this.submitMove(h.states(), performance.now(), { force: true, entry });
    h.timeline.push(entry);
    h.updateUndoButtons();
  }

  /** A gesture's entry: the current state's, to be filled in at its end. */
  newGestureEntry(): Entry | null {
    const cur = this.host.timeline.current;
    return cur ? derive(cur, { serverPos: -1, revision: null, draft: null, settings: this.host.currentSettings() }) : null;
  }

  dragStart(group: number): void {
    this.dragBase = cloneStates(this.host.states());
    this.dragGroup = group;
    this.dragGesture = newGesture();
    this.dragEntry = this.newGestureEntry();
    this.dragSent = false;
    dismissFirstHint();
  }
  dragMove(delta: THREE.Vector3, t0: number): void {
    const pick = this.pendingPick;
    if (pick) {
      // The handles are still being set: keep the newest travel, sent once they are.
      pick.delta = delta.clone();
      pick.t0 = t0;
      if (!pick.applied) return;
    }
    const i = this.dragGroup;
    if (!this.host.isHandle(i)) return;
    const st = cloneStates(this.dragBase);
    const b = this.dragBase[i].translation;
    st[i].translation = [b[0] + delta.x, b[1] + delta.y, b[2] + delta.z];
    this.submitMove(st, t0, { gesture: this.dragGesture, entry: this.dragEntry });
    this.dragSent = true;
    this.placeGizmo();
  }
  dragEnd(): void {
    const pick = this.pendingPick;
    if (pick && !pick.applied) {
      pick.released = true; // finished once the handles are set
      return;
    }
    this.finishGesture();
  }
  private finishGesture(): void {
    this.pendingPick = null;
    this.host.endCoarse();
    if (this.dragSent && this.dragEntry) {
      this.dragEntry.states = cloneStates(this.host.states());
      this.host.timeline.push(this.dragEntry);
    }
    this.dragEntry = null;
    this.dragSent = false;
    this.host.updateUndoButtons();
    this.host.updateReady();
  }

  // ---------- pick and drag ----------

  grabRadius(): number {
    return Number($in("grab-radius").value) * this.host.meshScale();
  }

  showGrabRadius(): void {
    $("grab-radius-val").textContent = `${(Number($in("grab-radius").value) * 100).toFixed(1)}% of size`;
  }

  radiusWheel(dy: number): void {
    const el = $in("grab-radius");
    // Wheel up (negative) grows it, as Blender's proportional size.
    const v = Math.min(Number(el.max), Math.max(Number(el.min), Number(el.value) * Math.exp(-dy / 600)));
    el.value = String(v);
    this.showGrabRadius();
    const interaction = this.host.interaction();
    const viewer = this.host.viewer();
    const hit = interaction.lastPointer && interaction.pickAt(viewer, interaction.lastPointer.x, interaction.lastPointer.y);
    viewer.setGrabPreview(hit ? hit.point : null, this.grabRadius());
  }

  /** A press on the mesh with Grab: the groups it adds are set, and the drag goes on meanwhile. */
  pickStart(hit: PickHit): boolean {
    const h = this.host;
    const s = h.session();
    if (!s || h.dirty() || h.historyBusy()) return false;
    const topo = h.topology(s);
    const specs = h.appliedSpecs();
    const res = pickGroups({
      positions: s.state.positions, adjacency: topo.adjacency, components: topo.components, groupOf: (v) => s.draft.groupOf(v),
      roles: specs.map((g) => g.role), point: [hit.point.x, hit.point.y, hit.point.z], faceVertices: hit.face, radius: this.grabRadius(),
    });
    if ("reason" in res) {
      h.banner.message(res.reason);
      return false;
    }
    h.banner.clearError();
    const next: GroupSpec[] = [...specs, { role: "handle", vertices: res.handle }];
    const handleIndex = next.length - 1;
    if (res.farFixed.length) next.push({ role: "fixed", vertices: res.farFixed });
    if (res.otherParts.length) next.push({ role: "fixed", vertices: res.otherParts });
    const pick: PendingPick = { delta: null, t0: performance.now(), applied: false, released: false, failed: false };
    this.pendingPick = pick;
    h.viewer().setGrabPreview(null, 0);
    dismissFirstHint();
    void (async () => {
      try {
        await h.setHandles(next);
      } catch (e) {
        pick.failed = true;
        this.pendingPick = null;
        h.fail("Pick failed", e, "handles");
        return;
      }
      if (this.pendingPick !== pick) return;
      h.selectGroup(handleIndex);
      this.dragBase = cloneStates(h.states());
      this.dragGroup = handleIndex;
      this.dragGesture = newGesture();
      this.dragEntry = this.newGestureEntry();
      this.dragSent = false;
      pick.applied = true;
      if (pick.delta) this.dragMove(pick.delta, pick.t0);
      if (pick.released) this.finishGesture();
    })();
    return true;
  }

  // ---------- gizmo, markers, target ghost ----------

  wireGizmo(): void {
    const viewer = this.host.viewer();
    const g = viewer.gizmo;
    g.attach(viewer.pivotObject);
    g.addEventListener("objectChange", () => {
      const o = viewer.pivotObject;
      const i = this.host.selectedHandle();
      const c = i >= 0 ? this.host.session()?.anchors[i]?.centroid : null;
      if (!c) return;
      // Uniform scale: take the axis the user pulled (largest change from the current scale).
      const sc = pulledScale(this.host.states()[i].scale, [o.scale.x, o.scale.y, o.scale.z]);
      o.scale.setScalar(sc);
      const q = o.quaternion;
      const st = cloneStates(this.host.states());
      st[i] = { translation: [o.position.x - c.x, o.position.y - c.y, o.position.z - c.z], rotation: [q.w, q.x, q.y, q.z], scale: sc };
      // One gizmo drag is one undo step on the server too.
      this.submitMove(st, performance.now(), { gesture: this.gizmoGesture, entry: this.dragEntry });
      this.dragSent = true;
      this.placeMarkers();
    });
    g.addEventListener("dragging-changed", (e: any) => {
      if (e.value) {
        this.gizmoGesture = newGesture();
        this.dragEntry = this.newGestureEntry();
        this.dragSent = false;
        dismissFirstHint();
      } else {
        this.gizmoGesture = 0n;
        this.finishGesture();
      }
    });
  }

  setGizmoMode(m: "translate" | "rotate" | "scale"): void {
    this.host.viewer().gizmo.setMode(m);
    for (const x of ["translate", "rotate", "scale"]) $(`gizmo-${x}`).classList.toggle("on", x === m);
  }

  /** Gizmo on the selected handle group, at pivot + translation (the centroid of its moved
   * anchors) with its R and s; a marker sphere on every other handle group. */
  placeGizmo(): void {
    const h = this.host;
    const s = h.session();
    const viewer = h.viewer();
    const o = viewer.pivotObject;
    const i = h.selectedHandle();
    const c = i >= 0 ? s?.anchors[i]?.centroid : null;
    const show = !!c && s!.role === "edit" && !s!.gone && h.tool() === "move" && !h.modalActive();
    viewer.gizmo.getHelper().visible = show;
    viewer.gizmo.enabled = show;
    const states = h.states();
    if (c && states[i]) {
      const m = states[i];
      o.position.set(c.x + m.translation[0], c.y + m.translation[1], c.z + m.translation[2]);
      o.quaternion.set(m.rotation[1], m.rotation[2], m.rotation[3], m.rotation[0]);
      o.scale.setScalar(m.scale);
    }
    this.placeMarkers();
  }

  private placeMarkers(): void {
    const h = this.host;
    const s = h.session();
    const tool = h.tool();
    if (!s || s.role !== "edit" || s.gone || (tool !== "move" && tool !== "grab")) {
      h.viewer().setMarkers([]);
      return;
    }
    const sel = h.selectedHandle();
    const states = h.states();
    const items = [];
    for (const i of h.handleIndices()) {
      const c = s.anchors[i]?.centroid;
      const t = states[i]?.translation;
      if (!c || !t) continue;
      items.push({ at: [c.x + t[0], c.y + t[1], c.z + t[2]] as [number, number, number], color: groupColor("handle", s.draft.ordinal(i)), selected: i === sel });
    }
    h.viewer().setMarkers(items);
  }

  /** While a move waits on a slow solve, dots show where the handle vertices are headed. */
  private scheduleTargetGhost(): void {
    clearTimeout(this.targetTimer);
    this.targetTimer = setTimeout(() => {
      const h = this.host;
      const s = h.session();
      if (!s || !h.coalescer.busy) return;
      const states = h.states();
      const pts: number[] = [];
      for (const i of h.handleIndices()) {
        const a = s.anchors[i];
        const c = a?.centroid;
        if (!a || !c || !states[i]) continue;
        for (let k = 0; k < a.positions.length; k += 3) {
          pts.push(...applyMove(states[i], [c.x, c.y, c.z], [a.positions[k], a.positions[k + 1], a.positions[k + 2]]));
        }
      }
      h.viewer().setTargets(Float32Array.from(pts));
    }, 250);
  }
}
