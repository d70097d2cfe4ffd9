// Wiring: the page's parts joined into one App, the controls that belong to no one part, and the
// test hooks (window.__meshdeform). Each part is in app/ and says what it owns:
// session_lifecycle.ts (boot, open, create, upload, close, a session gone), frames_view.ts (the
// Watch stream's frames on screen, the colours), groups_controller.ts (handle groups, tools,
// painting, readiness), moves_controller.ts (moves, drags, pick-and-drag, the gizmo),
// history_sync.ts (undo / redo kept in step with the server's history, Reset),
// settings_panel.ts (solver settings and view preferences), modal_transform.ts (G / R / S),
// keys.ts (the keyboard), page.ts (what several parts share); watch_stream.ts, mesh_files.ts, config.ts and session.ts are theirs.
import * as THREE from "three";
import type { MoveHandlesResponse } from "./gen/meshdeform/v1/deformation_pb";
import { MoveCoalescer } from "./coalescer";
import { rampCss } from "./distortion";
import { Timeline } from "./timeline";
import { Interaction } from "./interaction";
import { statesKey, type GroupStates } from "./moves";
import { Viewer3D } from "./scene";
import { Banner, $, $in } from "./ui/dom";
import { dismissFirstHint } from "./ui/notice";
import { ColorPainter } from "./ui/colors";
import { DragToFrame } from "./frame_latency";
import { makeHooks, newPageMetrics, type Hooks, type PageMetrics } from "./test_hooks";
import { ModalTransform } from "./app/modal_transform";
import { FramesView } from "./app/frames_view";
import { GroupsController } from "./app/groups_controller";
import { HistorySync } from "./app/history_sync";
import { onKey, type KeysHost } from "./app/keys";
import { MovesController } from "./app/moves_controller";
import { SessionLifecycle } from "./app/session_lifecycle";
import { SettingsPanel } from "./app/settings_panel";
import type { PageState } from "./app/page";
import type { MoveTarget, Session } from "./app/session";
import "./style.css";

class App {
  /** The test hooks (window.__meshdeform); the page's parts set their state fields. */
  readonly hooks: Hooks = makeHooks(this);
  readonly banner = new Banner((t) => (this.hooks.lastError = t));
  readonly canvas = $("canvas") as HTMLCanvasElement;
  viewer!: Viewer3D;
  interaction!: Interaction;
  colors!: ColorPainter;
  /** Every applied group's move (identity for fixed groups), absolute from its anchors. */
  states: GroupStates = [];
  readonly timeline = new Timeline();
  readonly modal = new ModalTransform({
    viewer: () => this.viewer,
    states: () => this.states,
    setStates: (st) => { this.states = st; },
    blocked: () => ({ dirty: this.groups.dirty, busy: this.history.busy || this.moves.picking }),
    lastPointer: () => this.interaction.lastPointer,
    selectedHandle: () => this.groups.selectedHandle(),
    handleIndices: () => this.groups.handleIndices(),
    selectGroup: (i) => this.groups.selectGroup(i),
    explainBlocked: () => {
      if (this.groups.dirty) this.groups.updateReady();
      else if (this.groups.handleIndices().length === 0) this.banner.message("Nothing to move with G, R or S yet: pick a point and drag it (Grab), or paint a handle.");
    },
    anchorCentroid: (i) => this.session?.anchors[i]?.centroid ?? null,
    newGestureEntry: () => this.moves.newGestureEntry(),
    setGizmoMode: (m) => this.moves.setGizmoMode(m),
    opened: () => dismissFirstHint(),
    placeGizmo: () => this.moves.placeGizmo(),
    submitMove: (st, t0, o) => this.moves.submitMove(st, t0, o),
    afterCommand: (entry) => {
      if (entry) this.timeline.push(entry);
      this.history.updateButtons();
    },
    revertSent: (base) => this.history.revertModal(base),
    endGesture: () => this.frames.endCoarse(),
    show: (text) => {
      $("keycmd").textContent = text;
      $("keycmd").hidden = !text;
      this.hooks.modal = text;
    },
  });

  readonly metrics: PageMetrics = newPageMetrics();
  private readonly dragToFrame = new DragToFrame(this.metrics.dragToFrameMs);

  private readonly settings: SettingsPanel = new SettingsPanel({
    session: () => this.session,
    viewer: () => this.viewer,
    resolve: () => this.moves.resolveWithSettings(),
    recolor: () => this.frames.recolor(),
    message: (text) => this.banner.message(text),
  });

  private readonly frames: FramesView = new FramesView({
    banner: this.banner, hooks: this.hooks, metrics: this.metrics, dragToFrame: this.dragToFrame,
    session: () => this.session,
    viewer: () => this.viewer,
    interaction: () => this.interaction,
    colors: () => this.colors,
    modalActive: () => this.modal.active,
    moveInFlight: () => this.coalescer.busy,
    heatMetric: () => this.settings.heatMetric(),
    heatMax: (metric) => this.settings.heatMax(metric),
    markGone: (s, detail) => this.sessions.markGone(s, detail),
    placeGizmo: () => this.moves.placeGizmo(),
  });

  readonly coalescer = new MoveCoalescer<MoveTarget, MoveHandlesResponse>({
    key: (t) => statesKey(t.states) + "|" + t.opts,
    send: (t) => this.moves.send(t),
    onResult: (r, t) => this.moves.onMoveResult(r, t),
    onError: (e) => this.sessions.fail("Move failed", e, "move"),
  });

  /** What the history, the groups and the moves all read (app/page.ts). */
  private readonly page: PageState = {
    banner: this.banner, hooks: this.hooks, timeline: this.timeline, coalescer: this.coalescer,
    session: () => this.session,
    viewer: () => this.viewer,
    states: () => this.states,
    setStates: (st) => { this.states = st; },
  };

  private readonly history: HistorySync = new HistorySync({
    ...this.page,
    dirty: () => this.groups.dirty,
    closeModal: () => this.modal.close(),
    fail: (prefix, e, action) => this.sessions.fail(prefix, e, action),
    handleIndices: () => this.groups.handleIndices(),
    appliedSpecs: () => this.groups.appliedSpecs(),
    applyHandles: () => this.groups.applyHandles(),
    setHandlesRaw: (specs) => this.groups.setHandlesRaw(specs),
    setHandles: (specs, capture) => this.groups.setHandles(specs, capture),
    showDraft: (specs) => this.groups.showDraft(specs),
    groupMoves: (st) => this.moves.groupMoves(st),
    settingsRequest: () => this.settings.request(),
    currentSettings: () => this.settings.currentSettings(),
    applySettings: (st) => this.settings.applySettings(st),
    recolor: () => this.frames.recolor(),
    renderGroups: () => this.groups.renderGroups(),
    updateReady: () => this.groups.updateReady(),
    placeGizmo: () => this.moves.placeGizmo(),
  });

  private readonly groups: GroupsController = new GroupsController({
    ...this.page,
    meshScale: () => this.meshScale(),
    setStatus: (text) => this.sessions.setStatus(text),
    fail: (prefix, e, action) => this.sessions.fail(prefix, e, action),
    method: () => this.settings.method(),
    currentSettings: () => this.settings.currentSettings(),
    updateMethodAvailability: () => this.settings.updateMethodAvailability(),
    resolveWithSettings: () => this.moves.resolveWithSettings(),
    captureRevisions: () => this.history.captureRevisions(),
    historyRestarted: () => this.history.restarted(),
    undo: () => this.history.undoRedo(false),
    updateUndoButtons: () => this.history.updateButtons(),
    recolor: () => this.frames.recolor(),
    placeGizmo: () => this.moves.placeGizmo(),
  });

  private readonly moves: MovesController = new MovesController({
    ...this.page, dragToFrame: this.dragToFrame,
    interaction: () => this.interaction,
    modalActive: () => this.modal.active,
    tool: () => this.groups.tool,
    dirty: () => this.groups.dirty,
    historyBusy: () => this.history.busy,
    handleIndices: () => this.groups.handleIndices(),
    isHandle: (i) => this.groups.isHandle(i),
    selectedHandle: () => this.groups.selectedHandle(),
    appliedSpecs: () => this.groups.appliedSpecs(),
    topology: (s) => this.groups.topology(s),
    setHandles: (specs) => this.groups.setHandles(specs),
    selectGroup: (i) => this.groups.selectGroup(i),
    fail: (prefix, e, action) => this.sessions.fail(prefix, e, action),
    optsKey: () => this.settings.optsKey(),
    currentSettings: () => this.settings.currentSettings(),
    settingsRequest: () => this.settings.request(),
    answered: (r, t) => this.history.answered(r, t),
    endCoarse: () => this.frames.endCoarse(),
    updateUndoButtons: () => this.history.updateButtons(),
    updateReady: () => this.groups.updateReady(),
    meshScale: () => this.meshScale(),
  });

  private readonly sessions: SessionLifecycle = new SessionLifecycle({
    banner: this.banner, hooks: this.hooks, coalescer: this.coalescer,
    viewer: () => this.viewer,
    closeModal: () => this.modal.close(),
    clearPick: () => this.moves.clearPick(),
    placeGizmo: () => this.moves.placeGizmo(),
    renderGroups: () => this.groups.renderGroups(),
    updateGroupButtons: () => this.groups.updateGroupButtons(),
    clearNotice: () => this.groups.clearNotice(),
    updateReady: () => this.groups.updateReady(),
    setHandles: (specs) => this.groups.setHandles(specs),
    startTool: () => this.groups.startTool(),
    adoptGroups: (groups, anchors) => this.groups.adoptGroups(groups, anchors),
    anchorsAreRest: (s) => this.groups.anchorsAreRest(s),
    showOpened: (settings, rigidity) => this.settings.showOpened(settings, rigidity),
    showRigidity: () => this.settings.showRigidity(),
    updateMethodAvailability: () => this.settings.updateMethodAvailability(),
    restoreHistory: (s, info, n) => this.history.restore(s, info, n),
    updateUndoButtons: () => this.history.updateButtons(),
    recolor: () => this.frames.recolor(),
    startStream: (s, indices) => this.frames.startStream(s, indices),
  });

  /** The open session (the lifecycle's). */
  get session(): Session | null {
    return this.sessions.current;
  }

  /** The state notice shown (the test hooks read it). */
  get noticeText(): string {
    return this.groups.noticeText;
  }

  start(): void {
    this.interaction = new Interaction(() => this.viewer, this.canvas, {
      tool: () => this.groups.tool,
      canEdit: () => this.sessions.canEdit(),
      canMove: () => !this.groups.dirty && !this.history.busy && !this.moves.picking,
      positions: () => this.session?.state.positions ?? null,
      handleGroups: () => this.groups.handleGroupViews(),
      groupOf: (v) => this.session?.draft.groupOf(v) ?? -1,
      select: (g) => this.groups.selectGroup(g),
      dragStart: (g) => this.moves.dragStart(g),
      dragMove: (d, t0) => this.moves.dragMove(d, t0),
      dragEnd: () => this.moves.dragEnd(),
      pickStart: (hit) => this.moves.pickStart(hit),
      hover: (hit) => {
        this.hooks.hovering = !!hit;
        this.viewer.setGrabPreview(hit ? hit.point : null, this.moves.grabRadius());
      },
      radiusWheel: (dy) => this.moves.radiusWheel(dy),
      modalActive: () => this.modal.active,
      modalPointer: (x, y) => this.modal.pointer(x, y),
      modalConfirm: () => this.modal.confirm(),
      modalCancel: () => this.modal.cancel(),
      paintStart: (extend) => this.groups.paintStart(extend),
      paint: (ix) => this.groups.paint(ix),
      paintEnd: () => this.groups.paintEnd(),
      brushRadius: () => Number($in("brush-radius").value) * this.meshScale(),
      inputDelay: (ms) => { if (this.metrics.inputDelayMs.length < 100_000) this.metrics.inputDelayMs.push(ms); },
    }, $("lasso-line") as unknown as SVGPolylineElement);
    this.viewer = new Viewer3D(this.canvas, () => this.interaction.attach());
    this.colors = new ColorPainter(this.viewer);
    this.moves.wireGizmo();
    this.wireControls();
    $("legend-bar").style.background = rampCss();
    void this.sessions.boot();
  }

  /** The controls of no one part: tools, gizmo modes, group buttons, views, undo / redo, keys. */
  private wireControls(): void {
    for (const t of ["move", "grab", "brush", "lasso"] as const) $(`tool-${t}`).addEventListener("click", () => this.groups.setTool(t));
    $("gizmo-translate").addEventListener("click", () => this.moves.setGizmoMode("translate"));
    $("gizmo-rotate").addEventListener("click", () => this.moves.setGizmoMode("rotate"));
    $("gizmo-scale").addEventListener("click", () => this.moves.setGizmoMode("scale"));
    $("apply-handles").addEventListener("click", () => void this.groups.applyHandles());
    $("clear-selection").addEventListener("click", () => this.groups.clearSelection());
    $("delete-group").addEventListener("click", () => void this.groups.deleteGroup(this.session?.draft.selected ?? -1));
    $("reset-rest").addEventListener("click", () => void this.history.resetToRest());
    const radius = () => ($("brush-radius-val").textContent = `${(Number($in("brush-radius").value) * 100).toFixed(1)}% of size`);
    $in("brush-radius").addEventListener("input", radius);
    radius();
    $in("grab-radius").addEventListener("input", () => this.moves.showGrabRadius());
    this.moves.showGrabRadius();
    this.settings.wire();
    $("reset-view").addEventListener("click", () => this.viewer.frame());
    $("view-front").addEventListener("click", () => this.viewer.setView("front"));
    $("view-side").addEventListener("click", () => this.viewer.setView("right"));
    $("view-top").addEventListener("click", () => this.viewer.setView("top"));
    $("undo").addEventListener("click", () => this.history.undoRedo(false));
    $("redo").addEventListener("click", () => this.history.undoRedo(true));
    const keys: KeysHost = {
      modal: this.modal,
      undoRedo: (redo) => this.history.undoRedo(redo),
      setView: (view) => this.viewer.setView(view),
      frame: () => this.viewer.frame(),
      canEdit: () => this.sessions.canEdit(),
      selectedGroup: () => this.session!.draft.selected,
      deleteGroup: (i) => void this.groups.deleteGroup(i),
    };
    window.addEventListener("keydown", (e) => onKey(e, keys));
    this.sessions.wire();
  }

  private meshScale(): number {
    const bb = this.viewer.geometry?.boundingBox;
    return bb ? bb.getSize(new THREE.Vector3()).length() : 1;
  }

  // ---------- test hooks ----------

  screenPoint(c: THREE.Vector3 | null): { x: number; y: number } | null {
    const p = c && this.viewer.toScreen(c.x, c.y, c.z);
    return p ? { x: p[0], y: p[1] } : null;
  }

  hookHandlePoint(): { x: number; y: number } | null {
    const views = this.groups.handleGroupViews();
    return this.screenPoint(views[0]?.centroid ?? null);
  }

  hookGroupPoint(i: number): { x: number; y: number } | null {
    const g = this.session?.groups[i];
    return g ? this.screenPoint(this.groups.centroidOf(g.vertices)) : null;
  }

  hookVertexPoint(v: number): { x: number; y: number } | null {
    const p = this.session?.state.positions;
    return p && v >= 0 && v * 3 < p.length ? this.screenPoint(new THREE.Vector3(p[v * 3], p[v * 3 + 1], p[v * 3 + 2])) : null;
  }
}

const app = new App();
(window as unknown as { __meshdeform: Hooks }).__meshdeform = app.hooks;
app.start();
