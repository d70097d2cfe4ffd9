// The handle groups, the tools and painting: the groups as painted (the session's draft) and as
// applied (SetHandles, a new epoch of the history), selecting, deleting and "fix the far side",
// brush and lasso strokes, the tool buttons, the group list and its buttons, and the page's
// readiness with the state notice (what is missing and the way out of it). Owns the tool, whether
// the painted groups differ from the applied ones, and the notice shown.
import * as THREE from "three";
import { create } from "@bufbuild/protobuf";
import { createContextValues } from "@connectrpc/connect";
import {
  HandleGroupSchema, HandleRole, type HandleGroup, type Method, type SetHandlesResponse,
} from "../gen/meshdeform/v1/deformation_pb";
import { kSessionId } from "../client";
import type { Action } from "../errors";
import { GroupSet, type GroupSpec } from "../groups";
import type { HandleGroupView, Tool } from "../interaction";
import { cloneStates, identityStates, planReset } from "../moves";
import { buildAdjacency, components, farSide } from "../pick";
import { progressText, readWithProgress } from "../progress";
import type { PaintMode } from "../selection";
import { derive, type Settings } from "../timeline";
import { $, $btn, $in, $sel } from "../ui/dom";
import { renderGroupList } from "../ui/groupsPanel";
import { clearStateNotice, showStateNotice, type NoticeAction } from "../ui/stateNotice";
import { client } from "./config";
import type { PageState } from "./page";
import { centroidOfRows, type Session } from "./session";

/** What the groups need from the page. */
export interface GroupsHost extends PageState {
  /** The mesh's size (its bounding box's diagonal). */
  meshScale(): number;
  setStatus(text: string): void;
  fail(prefix: string, e: unknown, action: Action): void;
  /** The method chosen (SetHandles prepares its solver). */
  method(): Method;
  currentSettings(): Settings;
  updateMethodAvailability(): void;
  /** Solves again with the controls' settings (a step of the history). */
  resolveWithSettings(): void;
  /** The history's server positions: taken before SetHandles replaces them, restarted after. */
  captureRevisions(): Promise<void>;
  historyRestarted(): void;
  undo(): void;
  updateUndoButtons(): void;
  recolor(): void;
  placeGizmo(): void;
}

export class GroupsController {
  tool: Tool = "move";
  /** The painted groups differ from the applied ones. */
  dirty = false;
  /** The state notice shown ("" for none). */
  noticeText = "";
  private magnifyPainted = false;

  constructor(private readonly host: GroupsHost) {}

  /** Indices (into the applied groups) of the HANDLE groups. */
  handleIndices(): number[] {
    const out: number[] = [];
    this.host.session()?.groups.forEach((g, i) => { if (g.role === HandleRole.HANDLE) out.push(i); });
    return out;
  }

  isHandle(i: number): boolean {
    return this.host.session()?.groups[i]?.role === HandleRole.HANDLE;
  }

  /** The selected group if it is an applied handle group (moves, gizmo, G/R/S), else -1. */
  selectedHandle(): number {
    const s = this.host.session();
    if (!s || this.dirty) return -1;
    const i = s.draft.selected;
    return this.isHandle(i) ? i : -1;
  }

  /** Adopts the applied groups; their anchors are `anchors` (the server's, 3 per vertex in group
   * order) when given, else the positions on screen (right after SetHandles they are the same). */
  adoptGroups(groups: HandleGroup[], anchors?: number[]): void {
    const s = this.host.session()!;
    const prevSelected = s.draft.selected;
    s.groups = groups.map((g) => create(HandleGroupSchema, { role: g.role, vertices: [...g.vertices] }));
    s.draft = new GroupSet(s.state.vertexCount, this.appliedSpecs());
    s.draft.select(prevSelected >= 0 && prevSelected < s.groups.length ? prevSelected : this.handleIndices()[0] ?? -1);
    const total = s.groups.reduce((n, g) => n + g.vertices.length, 0);
    const fromServer = anchors && anchors.length === 3 * total ? anchors : null;
    const p = s.state.positions;
    let row = 0;
    s.anchors = s.groups.map((g) => {
      const a = new Float32Array(g.vertices.length * 3);
      if (fromServer) {
        a.set(fromServer.slice(row * 3, (row + g.vertices.length) * 3));
        row += g.vertices.length;
      } else {
        g.vertices.forEach((v, k) => a.set(p.subarray(v * 3, v * 3 + 3), k * 3));
      }
      return { centroid: centroidOfRows(a), positions: a };
    });
    this.dirty = false;
    this.renderGroups();
  }

  /** True when every group's anchor is its rest position (to float precision): identity moves
   * then give the rest pose, and Reset can use them. */
  anchorsAreRest(s: Session): boolean {
    const tol = 1e-6 * Math.max(this.host.meshScale(), 1e-12);
    return s.groups.every((g, i) => g.vertices.every((v, k) =>
      [0, 1, 2].every((c) => Math.abs(s.anchors[i].positions[k * 3 + c] - s.rest[v * 3 + c]) <= tol)));
  }

  appliedSpecs(): GroupSpec[] {
    return (this.host.session()?.groups ?? []).map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" : "handle", vertices: [...g.vertices] }));
  }

  /** SetHandles for `specs` on the current shape: a new epoch of the history (not a step). */
  async setHandlesRaw(specs: GroupSpec[]): Promise<void> {
    const h = this.host;
    const s = h.session()!;
    const groups = specs.map((g) => create(HandleGroupSchema, { role: g.role === "fixed" ? HandleRole.FIXED : HandleRole.HANDLE, vertices: g.vertices }));
    await h.banner.progress("Factorizing…", async () => {
      h.banner.status("Factorizing…");
      const t = performance.now();
      // The streaming form reports the precompute's phases (seconds on a big mesh).
      const r = await readWithProgress<SetHandlesResponse>(
        client.setHandlesWithProgress(
          { sessionId: s.creds.sessionId, token: s.creds.token, groups, prepare: h.method() },
          { contextValues: createContextValues().set(kSessionId, s.creds.sessionId) },
        ),
        (p) => h.banner.status(progressText("Factorizing…", p)),
      );
      const nh = groups.filter((g) => g.role === HandleRole.HANDLE).length;
      h.setStatus(`Handles set (${nh} handle group${nh === 1 ? "" : "s"}, ${groups.length - nh} fixed) in ${((performance.now() - t) / 1000).toFixed(2)} s — drag a handle`);
      s.anchorsAtRest = s.state.revision === 0 && s.restKnown;
      this.adoptGroups(r.info?.groups.length ? r.info.groups : groups);
    });
    h.timeline.addEpoch({ groups: this.appliedSpecs(), anchors: s.anchors.map((a) => a.positions) });
    h.setStates(identityStates(s.groups.length));
    h.historyRestarted();
    h.coalescer.reset();
  }

  /** Sets new groups as a step of the history (the server's own history starts again). The
   * first groups of a session start the history: there is no state without groups to go back to. */
  async setHandles(specs: GroupSpec[], capture = true): Promise<void> {
    const h = this.host;
    const s = h.session()!;
    await h.coalescer.idle();
    const first = s.groups.length === 0;
    if (capture && !first && h.timeline.current) await h.captureRevisions();
    await this.setHandlesRaw(specs);
    if (first) h.timeline.clearEntries();
    h.timeline.push({
      epoch: h.timeline.live, serverPos: 0, states: cloneStates(h.states()), settings: h.currentSettings(), draft: null,
      revision: s.state.revision,
    });
    h.updateUndoButtons();
    h.recolor();
    this.updateReady();
    if (this.tool !== "move" && this.tool !== "grab") this.setTool("move");
  }

  /** Sends the painted groups (SetHandles). Returns false if they are not valid or the call failed. */
  async applyHandles(): Promise<boolean> {
    const s = this.host.session();
    if (!s || s.role !== "edit" || s.gone) return false;
    const msg = s.draft.validate();
    if (msg) {
      this.updateReady(); // the notice says what is missing, with its way out
      return false;
    }
    this.host.banner.clearError();
    try {
      await this.setHandles(s.draft.specs());
      return true;
    } catch (e) {
      this.host.fail("Apply handles failed", e, "handles");
      return false;
    }
  }

  selectGroup(i: number): void {
    const s = this.host.session();
    if (!s) return;
    s.draft.select(i);
    this.renderGroups();
    this.host.recolor();
    this.host.placeGizmo();
  }

  async deleteGroup(i: number): Promise<void> {
    const s = this.host.session();
    if (!s || s.role !== "edit" || s.gone || i < 0 || i >= s.draft.size) return;
    s.draft.delete(i);
    // Deleting takes effect at once when the rest is a valid set; else the notice says what is
    // missing (with one click to fix it, or undo).
    if (!s.draft.validate()) {
      this.host.banner.clearError();
      try {
        await this.setHandles(s.draft.specs());
      } catch (e) {
        this.host.fail("Delete failed", e, "handles");
        this.afterDraftChange(); // not applied: the painted groups say so
      }
      return;
    }
    this.afterDraftChange();
  }

  /** The painted groups changed: a step of the history (undo brings them back). */
  private afterDraftChange(): void {
    const s = this.host.session();
    if (!s) return;
    this.dirty = !s.draft.equals(this.appliedSpecs());
    const cur = this.host.timeline.current;
    if (cur) this.host.timeline.push(derive(cur, { draft: this.dirty ? s.draft.specs() : null }));
    this.renderGroups();
    this.host.recolor();
    this.host.updateUndoButtons();
    this.updateReady();
  }

  /** A history state's painted groups (null: the applied ones), the first handle selected. */
  showDraft(specs: GroupSpec[] | null): void {
    const s = this.host.session()!;
    s.draft = new GroupSet(s.state.vertexCount, specs ?? this.appliedSpecs());
    s.draft.select(this.handleIndices()[0] ?? -1);
    this.dirty = !s.draft.equals(this.appliedSpecs());
  }

  /** "Clear": no painted groups and no magnify region (a step of the history). */
  clearSelection(): void {
    this.host.banner.clearError();
    this.host.session()?.selection.clear();
    this.host.session()?.draft.clear();
    this.host.updateMethodAvailability();
    this.afterDraftChange();
  }

  /** "Fix the far side": a fixed group on the side of each handle's part away from the handles. */
  private async fixFarSide(): Promise<void> {
    const s = this.host.session();
    if (!s) return;
    const topo = this.topology(s);
    const specs = s.draft.specs();
    const taken = new Set(specs.flatMap((g) => g.vertices));
    const handles = specs.filter((g) => g.role === "handle").flatMap((g) => g.vertices);
    if (handles.length === 0) return;
    const c = centroidOfRows(handles.flatMap((v) => [...s.state.positions.subarray(v * 3, v * 3 + 3)]))!;
    const comp = topo.components.id[handles[0]];
    const far = farSide(s.state.positions, topo.components.id, comp, [c.x, c.y, c.z], (v) => taken.has(v));
    if (far.length === 0) return;
    s.draft.beginStroke("fixed", false);
    s.draft.paint(far);
    s.draft.endStroke();
    this.afterDraftChange();
    await this.applyHandles();
  }

  renderGroups(): void {
    const s = this.host.session();
    const editable = !!s && s.role === "edit" && !s.gone;
    renderGroupList(s?.draft ?? null, this.dirty, editable, { select: (i) => this.selectGroup(i), remove: (i) => void this.deleteGroup(i) });
    this.host.hooks.selectedGroup = s?.draft.selected ?? -1;
    this.updateGroupButtons();
  }

  updateGroupButtons(): void {
    const s = this.host.session();
    const edit = !!s && s.role === "edit" && !s.gone;
    $btn("delete-group").disabled = !edit || s!.draft.selected < 0;
    const plan = s ? planReset(s.restKnown, s.anchorsAtRest) : "unavailable";
    $btn("reset-rest").disabled = !edit || this.handleIndices().length === 0 || plan === "unavailable";
    $btn("reset-rest").title = plan === "unavailable"
      ? "The server no longer keeps this session's rest mesh (revision 0), so the rest pose is unknown here."
      : "Every handle back to its rest position; the mesh returns to the rest pose exactly (undoable)";
  }

  /** The centroid of vertices `vs` as rendered, or null for none. */
  centroidOf(vs: ArrayLike<number>): THREE.Vector3 | null {
    const p = this.host.session()?.state.positions;
    if (!p || vs.length === 0) return null;
    const c = new THREE.Vector3();
    for (let k = 0; k < vs.length; k++) c.add(new THREE.Vector3(p[vs[k] * 3], p[vs[k] * 3 + 1], p[vs[k] * 3 + 2]));
    return c.divideScalar(vs.length);
  }

  /** The applied handle groups with their rendered centroids, the selected one first. */
  handleGroupViews(): HandleGroupView[] {
    const s = this.host.session();
    if (!s) return [];
    const sel = this.selectedHandle();
    const idx = this.handleIndices().sort((a, b) => (a === sel ? -1 : b === sel ? 1 : a - b));
    return idx.map((i) => ({ index: i, vertices: s.groups[i].vertices, centroid: this.centroidOf(s.groups[i].vertices) }));
  }

  topology(s: Session): NonNullable<Session["topology"]> {
    if (!s.topology) {
      const adjacency = buildAdjacency(s.indices, s.state.vertexCount);
      s.topology = { adjacency, components: components(adjacency, s.state.vertexCount) };
    }
    return s.topology;
  }

  // ---------- painting ----------

  paintStart(extend: boolean): void {
    const s = this.host.session();
    const mode = $sel("paint-mode").value as PaintMode;
    if (!s || (mode !== "fixed" && mode !== "handle")) return;
    s.draft.beginStroke(mode, extend || $in("extend-group").checked);
  }

  paint(ix: number[]): void {
    const s = this.host.session();
    if (!s) return;
    const mode = $sel("paint-mode").value as PaintMode;
    if (ix.length === 0) {
      if (this.tool === "lasso") this.host.banner.message("The lasso selected no vertex facing the camera.");
      return;
    }
    if (mode === "fixed" || mode === "handle") s.draft.paint(ix);
    else if (mode === "erase") s.draft.erase(ix);
    s.selection.paint(ix, mode);
    if (mode === "magnify" || mode === "erase") this.magnifyPainted = true;
    this.host.recolor();
  }

  paintEnd(): void {
    const s = this.host.session();
    if (!s) return;
    s.draft.endStroke();
    if (this.magnifyPainted) {
      // The magnify region is a setting: one re-solve (one step) per stroke.
      this.magnifyPainted = false;
      this.host.updateMethodAvailability();
      this.dirty = !s.draft.equals(this.appliedSpecs());
      if (!this.dirty) {
        this.host.resolveWithSettings();
        this.renderGroups();
        this.host.recolor();
        this.updateReady();
        return;
      }
    }
    this.afterDraftChange();
  }

  // ---------- tools, readiness ----------

  setTool(t: Tool): void {
    // Back to Move with painted changes: apply them (that is what the user wants to drag).
    if ((t === "move" || t === "grab") && this.tool !== "move" && this.tool !== "grab" && this.dirty && this.host.session()?.draft.validate() === null) {
      this.tool = t;
      void this.applyHandles();
    }
    this.tool = t;
    this.host.hooks.tool = t;
    for (const x of ["move", "grab", "brush", "lasso"] as const) $(`tool-${x}`).classList.toggle("on", x === t);
    $("paint-opts").hidden = t === "move" || t === "grab";
    $("gizmo-modes").hidden = t !== "move";
    $("brush-radius-row").hidden = t !== "brush";
    $("grab-radius-row").hidden = t !== "grab";
    const viewer = this.host.viewer();
    viewer.orbit.enabled = true;
    if (t !== "grab") viewer.setGrabPreview(null, 0);
    this.host.placeGizmo();
    this.updateReady();
  }

  /** Nothing to drag on a mesh without groups (an upload): start with pick and drag. */
  startTool(): void {
    const s = this.host.session();
    if (s && s.role === "edit" && !s.gone && s.groups.length === 0 && s.draft.size === 0) this.setTool("grab");
  }

  /** No state notice. */
  clearNotice(): void {
    clearStateNotice();
    this.noticeText = "";
  }

  /** Readiness, the tool hint and the state notice: what is missing and the way out of it. */
  updateReady(): void {
    const h = this.host;
    const s = h.session();
    h.hooks.ready = !!s && !s.gone && s.state.hasSnapshot && this.handleIndices().length > 0 && !this.dirty;
    const edit = !!s && s.role === "edit" && !s.gone;
    const hint = $("hint");
    hint.hidden = true;
    if (!s || !edit) {
      this.clearNotice();
      this.updateGroupButtons();
      h.placeGizmo();
      return;
    }
    const actions: NoticeAction[] = [];
    let text = "";
    const pick: NoticeAction = { id: "notice-pick", label: "Pick & drag", run: () => this.setTool("grab") };
    const problem = s.draft.validate();
    if (s.draft.size === 0) {
      text = this.tool === "grab"
        ? "Nothing to drag yet: press on the mesh and drag. A handle forms around the point (its size: the wheel over the mesh, or Grab radius) and the far side stays fixed."
        : "Nothing to drag yet: pick a point and drag it, or paint a fixed region and a handle (Brush or Lasso).";
      if (this.tool !== "grab") actions.push(pick);
    } else if (problem && s.draft.roles().every((r) => r === "fixed")) {
      text = "No handle group: nothing can move. Pick a point on the mesh and drag it, or paint a handle (Brush, mode handle).";
      if (this.tool !== "grab") actions.push(pick);
      if (h.timeline.canUndo) actions.push({ id: "notice-undo", label: "Undo", run: () => h.undo() });
    } else if (problem) {
      text = "No fixed region: a handle alone would carry the whole mesh along. Fix the side of the mesh away from the handles, or paint a fixed region.";
      actions.push({ id: "notice-fix-far", label: "Fix the far side", run: () => void this.fixFarSide() });
      if (h.timeline.canUndo) actions.push({ id: "notice-undo", label: "Undo", run: () => h.undo() });
    } else if (this.dirty) {
      text = this.tool === "move"
        ? "The painted groups are not applied yet: apply them to drag."
        : "The painted groups are not applied yet: apply them (or switch to Move) to drag.";
      actions.push({ id: "notice-apply", label: "Apply handles", run: () => void this.applyHandles() });
    }
    if (text) showStateNotice(text, actions);
    else clearStateNotice();
    this.noticeText = text;
    this.updateGroupButtons();
    h.placeGizmo();
  }
}
