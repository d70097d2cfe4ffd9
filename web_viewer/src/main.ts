// Wiring: session lifecycle, moves and the test hooks (the G/R/S commands, the Watch worker and
// its frames on screen, the undo history, the handle groups with the tools and painting, file
// transfers, the address settings and the settings panel are in app/).
import * as THREE from "three";
import { Code, ConnectError } from "@connectrpc/connect";
import {
  HandleRole, MeshFormat,
  type CreateSessionResponse, type MoveHandlesResponse, type SessionInfo,
} from "./gen/meshdeform/v1/deformation_pb";
import { progressText, readWithProgress } from "./progress";
import { MoveCoalescer } from "./coalescer";
import { rampCss } from "./distortion";
import { errorCode, type Action } from "./errors";
import { GroupSet, groupColor, type GroupSpec } from "./groups";
import { parseGlb } from "./glb";
import { newGesture, settingsView } from "./edit_state";
import { derive, Timeline, type Entry } from "./timeline";
import { Interaction, type PickHit } from "./interaction";
import {
  applyMove, cloneStates, statesKey, toGroupMove,
  type GroupStates,
} from "./moves";
import { pickGroups } from "./pick";
import { Viewer3D } from "./scene";
import { SelectionState } from "./selection";
import { formatHash, parseLink, shareLink, type Credentials } from "./share";
import { Banner, $, $in } from "./ui/dom";
import { showCounts } from "./ui/metrics";
import { dismissFirstHint, hideLinkProblem, showFirstHint, showLinkProblem } from "./ui/notice";
import { ColorPainter } from "./ui/colors";
import { decoderReady, PositionState } from "./updates";
import { viewForKey } from "./views";
import { DragToFrame } from "./frame_latency";
import { makeHooks, newPageMetrics, type Hooks, type PageMetrics, type Role } from "./test_hooks";
import { ModalTransform } from "./app/modal_transform";
import { createSessionFromFile, downloadMesh, formatOfName } from "./app/mesh_files";
import { client, EDIT_CONTROLS, GONE_TEXT, LAMBDA, query } from "./app/config";
import { FramesView } from "./app/frames_view";
import { GroupsController } from "./app/groups_controller";
import { HistorySync } from "./app/history_sync";
import { SettingsPanel } from "./app/settings_panel";
import type { MoveTarget, PendingPick, Session } from "./app/session";
import "./style.css";

class App {
  /** The test hooks (window.__meshdeform); the page's parts set their state fields. */
  readonly hooks: Hooks = makeHooks(this);
  readonly banner = new Banner((t) => (this.hooks.lastError = t));
  readonly canvas = $("canvas") as HTMLCanvasElement;
  viewer!: Viewer3D;
  interaction!: Interaction;
  colors!: ColorPainter;
  session: Session | null = null;
  /** Every applied group's move (identity for fixed groups), absolute from its anchors. */
  states: GroupStates = [];
  readonly timeline = new Timeline();
  readonly modal = new ModalTransform({
    viewer: () => this.viewer,
    states: () => this.states,
    setStates: (st) => { this.states = st; },
    blocked: () => ({ dirty: this.groups.dirty, busy: this.history.busy || !!this.pendingPick }),
    lastPointer: () => this.interaction.lastPointer,
    selectedHandle: () => this.groups.selectedHandle(),
    handleIndices: () => this.groups.handleIndices(),
    selectGroup: (i) => this.groups.selectGroup(i),
    explainBlocked: () => {
      if (this.groups.dirty) this.groups.updateReady();
      else if (this.groups.handleIndices().length === 0) this.banner.message("Nothing to move with G, R or S yet: pick a point and drag it (Grab), or paint a handle.");
    },
    anchorCentroid: (i) => this.session?.anchors[i]?.centroid ?? null,
    newGestureEntry: () => this.newGestureEntry(),
    setGizmoMode: (m) => this.setGizmoMode(m),
    opened: () => dismissFirstHint(),
    placeGizmo: () => this.placeGizmo(),
    submitMove: (st, t0, o) => this.submitMove(st, t0, o),
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
  private pendingPick: PendingPick | null = null;
  private sessionStatus = "";
  private targetTimer: ReturnType<typeof setTimeout> | undefined;
  readonly metrics: PageMetrics = newPageMetrics();
  private readonly dragToFrame = new DragToFrame(this.metrics.dragToFrameMs);
  private readonly settings: SettingsPanel = new SettingsPanel({
    session: () => this.session,
    viewer: () => this.viewer,
    resolve: () => this.resolveWithSettings(),
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
    markGone: (s, detail) => this.markGone(s, detail),
    placeGizmo: () => this.placeGizmo(),
  });

  readonly coalescer = new MoveCoalescer<MoveTarget, MoveHandlesResponse>({
    key: (t) => statesKey(t.states) + "|" + t.opts,
    send: (t) => this.sendMove(t),
    onResult: (r, t) => this.onMoveResult(r, t),
    onError: (e) => this.fail("Move failed", e, "move"),
  });

  private readonly history: HistorySync = new HistorySync({
    banner: this.banner, hooks: this.hooks, timeline: this.timeline, coalescer: this.coalescer,
    session: () => this.session,
    states: () => this.states,
    setStates: (st) => { this.states = st; },
    dirty: () => this.groups.dirty,
    closeModal: () => this.modal.close(),
    fail: (prefix, e, action) => this.fail(prefix, e, action),
    handleIndices: () => this.groups.handleIndices(),
    appliedSpecs: () => this.groups.appliedSpecs(),
    applyHandles: () => this.groups.applyHandles(),
    setHandlesRaw: (specs) => this.groups.setHandlesRaw(specs),
    setHandles: (specs, capture) => this.groups.setHandles(specs, capture),
    showDraft: (specs) => this.groups.showDraft(specs),
    groupMoves: (st) => this.groupMoves(st),
    settingsRequest: () => this.settings.request(),
    currentSettings: () => this.settings.currentSettings(),
    applySettings: (st) => this.settings.applySettings(st),
    recolor: () => this.frames.recolor(),
    renderGroups: () => this.groups.renderGroups(),
    updateReady: () => this.groups.updateReady(),
    placeGizmo: () => this.placeGizmo(),
  });

  private readonly groups: GroupsController = new GroupsController({
    banner: this.banner, hooks: this.hooks, timeline: this.timeline, coalescer: this.coalescer,
    session: () => this.session,
    viewer: () => this.viewer,
    states: () => this.states,
    setStates: (st) => { this.states = st; },
    meshScale: () => this.meshScale(),
    setStatus: (text) => this.setStatus(text),
    fail: (prefix, e, action) => this.fail(prefix, e, action),
    method: () => this.settings.method(),
    currentSettings: () => this.settings.currentSettings(),
    updateMethodAvailability: () => this.settings.updateMethodAvailability(),
    resolveWithSettings: () => this.resolveWithSettings(),
    captureRevisions: () => this.history.captureRevisions(),
    historyRestarted: () => this.history.restarted(),
    undo: () => this.history.undoRedo(false),
    updateUndoButtons: () => this.history.updateButtons(),
    recolor: () => this.frames.recolor(),
    placeGizmo: () => this.placeGizmo(),
  });

  /** The state notice shown (the test hooks read it). */
  get noticeText(): string {
    return this.groups.noticeText;
  }

  start(): void {
    this.interaction = new Interaction(() => this.viewer, this.canvas, {
      tool: () => this.groups.tool,
      canEdit: () => this.canEdit(),
      canMove: () => !this.groups.dirty && !this.history.busy && !this.pendingPick,
      positions: () => this.session?.state.positions ?? null,
      handleGroups: () => this.groups.handleGroupViews(),
      groupOf: (v) => this.session?.draft.groupOf(v) ?? -1,
      select: (g) => this.groups.selectGroup(g),
      dragStart: (g) => this.dragStart(g),
      dragMove: (d, t0) => this.dragMove(d, t0),
      dragEnd: () => this.dragEnd(),
      pickStart: (hit) => this.pickStart(hit),
      hover: (hit) => {
        this.hooks.hovering = !!hit;
        this.viewer.setGrabPreview(hit ? hit.point : null, this.grabRadius());
      },
      radiusWheel: (dy) => this.radiusWheel(dy),
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
    this.wireGizmo();
    this.wireControls();
    $("legend-bar").style.background = rampCss();
    void this.boot();
  }

  canEdit(): boolean {
    const s = this.session;
    return !!s && s.role === "edit" && !s.gone && s.state.hasSnapshot;
  }

  // ---------- session lifecycle ----------

  private async boot(): Promise<void> {
    const link = parseLink(location.hash);
    if (link.kind === "incomplete") {
      // Never replace a broken link with a new session silently: the user may be looking for
      // someone's work. Say so, and offer a new session.
      this.linkProblem(link.missing === "token"
        ? "The link names a session but has no token (it was probably cut off when copied). Ask for the full link, or start a new session."
        : "The link has a token but no session id (it was probably cut off when copied). Ask for the full link, or start a new session.");
      return;
    }
    try {
      await decoderReady();
      if (link.kind === "session") {
        await this.banner.progress("Opening session…", () => this.openExisting(link.creds));
      } else {
        await this.banner.progress("Creating session…", () => this.createFromSample(query.get("sample") || "cylinder"));
        showFirstHint();
      }
    } catch (e) {
      const code = errorCode(e);
      if (link.kind === "session" && !this.session && (code === Code.NotFound || code === Code.PermissionDenied || code === Code.InvalidArgument)) {
        this.linkProblem(code === Code.NotFound ? GONE_TEXT
          : code === Code.PermissionDenied ? "The link's token does not open this session (it may be mistyped or belong to another session)."
          : "The link is malformed.");
        return;
      }
      this.banner.error("Could not start", e, link.kind === "session" ? "open" : "create");
      this.banner.status("Not connected");
    }
  }

  /** Shows the broken-link notice; nothing is created and the edit controls stay off. */
  private linkProblem(detail: string): void {
    this.hooks.gone = true;
    this.hooks.ready = false;
    this.setEditEnabled(false);
    $("role").textContent = this.session ? "Session gone" : "No session";
    this.groups.renderGroups();
    this.banner.status("No session open");
    this.groups.clearNotice();
    showLinkProblem(detail, () => {
      // Same page without the fragment: a fresh demo session (the query, e.g. ?sample=, is kept).
      location.assign(location.pathname + location.search);
    });
  }

  /** The open session answered NOT_FOUND: it is gone. Stop editing and say so. */
  private markGone(s: Session, detail = GONE_TEXT): void {
    if (s.gone) return;
    s.gone = true;
    s.worker?.terminate();
    s.worker = null;
    this.coalescer.reset();
    this.modal.close();
    this.linkProblem(detail);
    this.placeGizmo();
  }

  /** Reports a failed call in plain words; NOT_FOUND on the open session means it is gone. */
  private fail(prefix: string, e: unknown, action: Action): void {
    const s = this.session;
    if (s && errorCode(e) === Code.NotFound && action !== "upload") {
      this.banner.error(prefix, e, action);
      this.markGone(s);
      return;
    }
    this.banner.error(prefix, e, action);
  }

  private async createFromSample(sample: string): Promise<void> {
    this.setStatus(`Creating session from sample “${sample}”…`);
    const r = await readWithProgress<CreateSessionResponse>(client.createSessionWithProgress({ source: { case: "sample", value: sample }, lambda: LAMBDA }), (p) =>
      this.banner.status(progressText(`Creating session from sample “${sample}”…`, p)),
    );
    const creds = { sessionId: r.sessionId, token: r.editToken };
    await this.load(creds, "edit", r.info!, r.viewToken, r.editToken);
    if (r.suggestedGroups.length) {
      await this.groups.setHandles(r.suggestedGroups.map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" as const : "handle" as const, vertices: [...g.vertices] })));
    }
    this.groups.startTool();
    history.replaceState(null, "", location.pathname + location.search + formatHash(creds));
  }

  private async openExisting(creds: Credentials): Promise<void> {
    // The server says what the token allows (and hands an editor the view token to share).
    const r = await client.getSessionInfo({ sessionId: creds.sessionId, token: creds.token });
    const info = r.info!;
    const role: Role = r.canEdit ? "edit" : "view";
    // The server hands out the groups' anchors, settings and undo history: the page continues
    // exactly where the last one left off, without setting the handles again.
    await this.load(creds, role, info, r.canEdit ? r.viewToken : creds.token, r.canEdit ? creds.token : null);
    this.groups.startTool();
  }

  /** Loads faces + rest positions, switches the screen to this session, opens Watch. */
  private async load(creds: Credentials, role: Role, info: SessionInfo, viewToken: string | null, editToken: string | null): Promise<void> {
    // Rest mesh (revision 0) for the heat map, the ghost and Reset; fall back to the current one if not kept.
    let glb;
    let restKnown = true;
    try {
      glb = await client.getMesh({ sessionId: creds.sessionId, token: creds.token, format: MeshFormat.GLB, revision: 0n });
    } catch (e) {
      if (ConnectError.from(e).code !== Code.NotFound) throw e;
      glb = await client.getMesh({ sessionId: creds.sessionId, token: creds.token, format: MeshFormat.GLB });
      restKnown = false;
    }
    const mesh = parseGlb(glb.meshBytes);
    const n = mesh.positions.length / 3;
    if (n !== info.vertices) throw new Error(`GLB has ${n} vertices, session ${info.vertices}`);
    this.closeCurrent();
    hideLinkProblem();
    this.hooks.gone = false;
    // The controls take the session's settings (those of its last move) so that a reload or a
    // shared link continues with them; a session without moves keeps the user's current choices
    // except the scale control, which starts at the session's (what its moves use unless told).
    const settings = info.edit?.settings ? settingsView(info.edit.settings) : null;
    this.settings.showOpened(settings, info.rigidity);
    let resolveSnapshot!: () => void;
    const gotSnapshot = new Promise<void>((r) => (resolveSnapshot = r));
    const state = new PositionState(n);
    const s: Session = {
      creds, role, viewToken, editToken, indices: mesh.indices, rest: Float32Array.from(mesh.positions), restKnown,
      state, selection: new SelectionState(n), draft: new GroupSet(n), groups: [], anchors: [],
      anchorsAtRest: false, gone: false, worker: null, gotSnapshot, resolveSnapshot, heat: null, heatMetric: null, topology: null,
    };
    state.positions.set(mesh.positions);
    this.session = s;
    this.viewer.setMesh(mesh.positions, mesh.indices);
    this.viewer.setGhost($in("ghost-rest").checked, s.rest);
    this.hooks.sessionId = creds.sessionId;
    this.hooks.role = role;
    this.hooks.vertexCount = n;
    this.hooks.revision = -1;
    this.setRole(role);
    this.settings.showRigidity();
    showCounts(info.vertices, info.faces);
    if (settings) {
      s.selection.clear();
      s.selection.paint(settings.magnifyVertices.filter((v) => v < n), "magnify");
    }
    this.groups.adoptGroups(info.groups, info.groupAnchors);
    // The session's undo history and the groups' current moves, as the server keeps them.
    this.history.restore(s, info, n);
    this.settings.updateMethodAvailability();
    this.frames.recolor();
    this.setStatus(`Session ${creds.sessionId.slice(0, 8)}… · ${info.vertices.toLocaleString("en")} vertices`);
    this.frames.startStream(s, mesh.indices);
    await gotSnapshot;
    // Opened at revision 0 (the normal case for a new session): the groups' anchors are the rest pose.
    s.anchorsAtRest = (restKnown && s.state.revision === 0) || (restKnown && this.groups.anchorsAreRest(s));
    this.groups.updateReady();
  }

  private closeCurrent(): void {
    const s = this.session;
    if (!s) return;
    s.worker?.terminate();
    s.worker = null;
    this.session = null;
    this.hooks.ready = false;
    this.coalescer.reset();
    this.modal.close();
    this.pendingPick = null;
  }

  private setRole(role: Role): void {
    document.body.classList.toggle("viewer-readonly", role === "view");
    const el = $("role");
    el.textContent = role === "view" ? "Watching (read-only)" : "Editing";
    el.classList.toggle("view", role === "view");
    this.setEditEnabled(role === "edit");
  }

  private setEditEnabled(on: boolean): void {
    for (const id of EDIT_CONTROLS) ($(id) as HTMLInputElement).disabled = !on;
    $in("upload-input").disabled = this.session?.role === "view";
    if (on) {
      this.settings.showRigidity();
      this.settings.updateMethodAvailability();
      this.history.updateButtons();
      this.groups.updateGroupButtons();
    }
  }

  private setStatus(text: string): void {
    this.sessionStatus = text;
    this.banner.status(text);
  }

  // ---------- settings ----------

  /** A setting changed: solve again with it, as a step of the history (the server also keeps it
   * for the next page that opens the session). */
  private resolveWithSettings(): void {
    const cur = this.timeline.current;
    if (this.groups.handleIndices().length === 0 || !cur || this.groups.dirty) return;
    const entry = derive(cur, { settings: this.settings.currentSettings(), serverPos: -1, revision: null, draft: null });
    this.submitMove(this.states, performance.now(), { force: true, entry });
    this.timeline.push(entry);
    this.history.updateButtons();
  }

  // ---------- moves ----------

  private submitMove(states: GroupStates, t0: number, o: { force?: boolean; gesture?: bigint; entry?: Entry | null } = {}): void {
    const s = this.session;
    if (!s || s.gone || this.groups.handleIndices().length === 0 || s.role !== "edit") return;
    this.states = cloneStates(states);
    this.coalescer.submit({ states: cloneStates(states), t0, opts: this.settings.optsKey(), gesture: o.gesture ?? 0n, entry: o.entry ?? null }, o.force ?? false);
    this.scheduleTargetGhost();
  }

  /** The moves of every handle group about the live anchors (moves are absolute). */
  private groupMoves(states: GroupStates) {
    const s = this.session!;
    return this.groups.handleIndices().map((i) => {
      const c = s.anchors[i]?.centroid ?? new THREE.Vector3();
      return toGroupMove(i, states[i], [c.x, c.y, c.z]);
    });
  }

  private sendMove(t: MoveTarget): Promise<MoveHandlesResponse> {
    const s = this.session!;
    return client.moveHandles(
      { sessionId: s.creds.sessionId, token: s.creds.token, moves: this.groupMoves(t.states), gesture: t.gesture, ...this.settings.request() },
      { timeoutMs: 60_000 },
    );
  }

  /** A move's answer: its server step (for the history) and the latency bookkeeping. */
  private onMoveResult(r: MoveHandlesResponse, t: MoveTarget | null): void {
    this.history.answered(r, t);
    const rev = Number(r.result?.revision ?? -1);
    if (rev < 0 || !t) return;
    // Geometry comes from Watch only (in order); the response is for flow control and latency.
    this.dragToFrame.answered(rev, t.t0, this.session?.state.revision ?? -1);
  }

  private dragBase: GroupStates = [];
  private dragGroup = -1;
  private dragGesture = 0n;
  private dragEntry: Entry | null = null;
  private dragSent = false;
  private gizmoGesture = 0n;

  /** A gesture's entry: the current state's, to be filled in at its end. */
  private newGestureEntry(): Entry | null {
    const cur = this.timeline.current;
    return cur ? derive(cur, { serverPos: -1, revision: null, draft: null, settings: this.settings.currentSettings() }) : null;
  }

  private dragStart(group: number): void {
    this.dragBase = cloneStates(this.states);
    this.dragGroup = group;
    this.dragGesture = newGesture();
    this.dragEntry = this.newGestureEntry();
    this.dragSent = false;
    dismissFirstHint();
  }
  private dragMove(delta: THREE.Vector3, t0: number): void {
    const pick = this.pendingPick;
    if (pick) {
      // The handles are still being set: keep the newest travel, sent once they are.
      pick.delta = delta.clone();
      pick.t0 = t0;
      if (!pick.applied) return;
    }
    const i = this.dragGroup;
    if (!this.groups.isHandle(i)) return;
    const st = cloneStates(this.dragBase);
    const b = this.dragBase[i].translation;
    st[i].translation = [b[0] + delta.x, b[1] + delta.y, b[2] + delta.z];
    this.submitMove(st, t0, { gesture: this.dragGesture, entry: this.dragEntry });
    this.dragSent = true;
    this.placeGizmo();
  }
  private dragEnd(): void {
    const pick = this.pendingPick;
    if (pick && !pick.applied) {
      pick.released = true; // finished once the handles are set
      return;
    }
    this.finishGesture();
  }
  private finishGesture(): void {
    this.pendingPick = null;
    this.frames.endCoarse();
    if (this.dragSent && this.dragEntry) {
      this.dragEntry.states = cloneStates(this.states);
      this.timeline.push(this.dragEntry);
    }
    this.dragEntry = null;
    this.dragSent = false;
    this.history.updateButtons();
    this.groups.updateReady();
  }

  // ---------- pick and drag ----------

  private grabRadius(): number {
    return Number($in("grab-radius").value) * this.meshScale();
  }

  private showGrabRadius(): void {
    $("grab-radius-val").textContent = `${(Number($in("grab-radius").value) * 100).toFixed(1)}% of size`;
  }

  private radiusWheel(dy: number): void {
    const el = $in("grab-radius");
    // Wheel up (negative) grows it, as Blender's proportional size.
    const v = Math.min(Number(el.max), Math.max(Number(el.min), Number(el.value) * Math.exp(-dy / 600)));
    el.value = String(v);
    this.showGrabRadius();
    const hit = this.interaction.lastPointer && this.interaction.pickAt(this.viewer, this.interaction.lastPointer.x, this.interaction.lastPointer.y);
    this.viewer.setGrabPreview(hit ? hit.point : null, this.grabRadius());
  }

  /** A press on the mesh with Grab: the groups it adds are set, and the drag goes on meanwhile. */
  private pickStart(hit: PickHit): boolean {
    const s = this.session;
    if (!s || this.groups.dirty || this.history.busy) return false;
    const topo = this.groups.topology(s);
    const specs = this.groups.appliedSpecs();
    const res = pickGroups({
      positions: s.state.positions, adjacency: topo.adjacency, components: topo.components, groupOf: (v) => s.draft.groupOf(v),
      roles: specs.map((g) => g.role), point: [hit.point.x, hit.point.y, hit.point.z], faceVertices: hit.face, radius: this.grabRadius(),
    });
    if ("reason" in res) {
      this.banner.message(res.reason);
      return false;
    }
    this.banner.clearError();
    const next: GroupSpec[] = [...specs, { role: "handle", vertices: res.handle }];
    const handleIndex = next.length - 1;
    if (res.farFixed.length) next.push({ role: "fixed", vertices: res.farFixed });
    if (res.otherParts.length) next.push({ role: "fixed", vertices: res.otherParts });
    const pick: PendingPick = { delta: null, t0: performance.now(), applied: false, released: false, failed: false };
    this.pendingPick = pick;
    this.viewer.setGrabPreview(null, 0);
    dismissFirstHint();
    void (async () => {
      try {
        await this.groups.setHandles(next);
      } catch (e) {
        pick.failed = true;
        this.pendingPick = null;
        this.fail("Pick failed", e, "handles");
        return;
      }
      if (this.pendingPick !== pick) return;
      this.groups.selectGroup(handleIndex);
      this.dragBase = cloneStates(this.states);
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

  // ---------- keys ----------

  private onKey(e: KeyboardEvent): void {
    const el = e.target as HTMLElement | null;
    const typing = (el?.tagName === "INPUT" && (el as HTMLInputElement).type !== "range" && (el as HTMLInputElement).type !== "checkbox") || el?.tagName === "SELECT" || el?.tagName === "TEXTAREA";
    if (typing) return;
    if (this.modal.active && !e.ctrlKey && !e.metaKey && !e.altKey) {
      e.preventDefault();
      this.modal.feed(e.key);
      return;
    }
    if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") {
      e.preventDefault();
      this.history.undoRedo(e.shiftKey);
      return;
    }
    if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "y") {
      e.preventDefault();
      this.history.undoRedo(true);
      return;
    }
    const view = !e.altKey && !e.metaKey ? viewForKey(e.code, e.key, e.ctrlKey) : null;
    if (view) {
      e.preventDefault();
      this.viewer.setView(view);
      return;
    }
    if (!e.ctrlKey && !e.metaKey && !e.altKey && (e.key === "Home" || e.key === "f" || e.key === "F")) {
      e.preventDefault();
      this.viewer.frame();
      return;
    }
    if (!e.ctrlKey && !e.metaKey && !e.altKey && this.canEdit()) {
      if (e.key === "Delete") {
        const i = this.session!.draft.selected;
        if (i >= 0) {
          e.preventDefault();
          void this.groups.deleteGroup(i);
        }
      } else if (this.modal.start(e.key)) {
        e.preventDefault();
      }
    }
  }

  // ---------- controls ----------

  private setGizmoMode(m: "translate" | "rotate" | "scale"): void {
    this.viewer.gizmo.setMode(m);
    for (const x of ["translate", "rotate", "scale"]) $(`gizmo-${x}`).classList.toggle("on", x === m);
  }

  private wireControls(): void {
    for (const t of ["move", "grab", "brush", "lasso"] as const) $(`tool-${t}`).addEventListener("click", () => this.groups.setTool(t));
    $("gizmo-translate").addEventListener("click", () => this.setGizmoMode("translate"));
    $("gizmo-rotate").addEventListener("click", () => this.setGizmoMode("rotate"));
    $("gizmo-scale").addEventListener("click", () => this.setGizmoMode("scale"));
    $("apply-handles").addEventListener("click", () => void this.groups.applyHandles());
    $("clear-selection").addEventListener("click", () => this.groups.clearSelection());
    $("delete-group").addEventListener("click", () => void this.groups.deleteGroup(this.session?.draft.selected ?? -1));
    $("reset-rest").addEventListener("click", () => void this.history.resetToRest());
    const radius = () => ($("brush-radius-val").textContent = `${(Number($in("brush-radius").value) * 100).toFixed(1)}% of size`);
    $in("brush-radius").addEventListener("input", radius);
    radius();
    $in("grab-radius").addEventListener("input", () => this.showGrabRadius());
    this.showGrabRadius();
    this.settings.wire();
    $("reset-view").addEventListener("click", () => this.viewer.frame());
    $("view-front").addEventListener("click", () => this.viewer.setView("front"));
    $("view-side").addEventListener("click", () => this.viewer.setView("right"));
    $("view-top").addEventListener("click", () => this.viewer.setView("top"));
    $("undo").addEventListener("click", () => this.history.undoRedo(false));
    $("redo").addEventListener("click", () => this.history.undoRedo(true));
    window.addEventListener("keydown", (e) => this.onKey(e));
    $("share").addEventListener("click", () => this.toggleShare());
    for (const b of document.querySelectorAll<HTMLButtonElement>("[data-copy]")) {
      b.addEventListener("click", () => {
        const input = $in(b.dataset.copy!);
        input.select();
        void navigator.clipboard?.writeText(input.value).catch(() => document.execCommand("copy"));
        b.textContent = "Copied";
        setTimeout(() => (b.textContent = "Copy"), 1200);
      });
    }
    $in("upload-input").addEventListener("change", () => {
      const f = $in("upload-input").files?.[0];
      if (f) void this.upload(f);
      $in("upload-input").value = "";
    });
    const stage = $("stage");
    stage.addEventListener("dragover", (e) => {
      if (this.session?.role === "view") return;
      e.preventDefault();
      $("drop").hidden = false;
    });
    stage.addEventListener("dragleave", () => ($("drop").hidden = true));
    stage.addEventListener("drop", (e) => {
      e.preventDefault();
      $("drop").hidden = true;
      const f = e.dataTransfer?.files?.[0];
      if (f && this.session?.role !== "view") void this.upload(f);
    });
    $("download-glb").addEventListener("click", () => void this.download(MeshFormat.GLB, "glb", "model/gltf-binary"));
    $("download-obj").addEventListener("click", () => void this.download(MeshFormat.OBJ, "obj", "text/plain"));
  }

  private toggleShare(): void {
    const box = $("share-box");
    const s = this.session;
    if (!s) return;
    const base = [location.origin, location.pathname] as const;
    $in("share-view-link").value = s.viewToken ? shareLink(...base, { sessionId: s.creds.sessionId, token: s.viewToken }) : "(unknown: open the session from its creator's page)";
    $in("share-edit-link").value = s.editToken ? shareLink(...base, { sessionId: s.creds.sessionId, token: s.editToken }) : "(read-only: no edit link)";
    box.hidden = !box.hidden;
  }

  private async upload(file: File): Promise<void> {
    const { ext, format } = formatOfName(file.name);
    if (format === null) {
      this.banner.message(`Upload failed: unsupported file type “.${ext}” (use .obj .off .ply .stl .glb .gltf)`);
      return;
    }
    this.banner.clearError();
    const before = this.sessionStatus;
    try {
      await this.banner.progress(`Uploading ${file.name}…`, async () => {
        const r = await createSessionFromFile(file, format, (text) => this.banner.status(text));
        const creds = { sessionId: r.sessionId, token: r.editToken };
        await this.load(creds, "edit", r.info!, r.viewToken, r.editToken);
        this.groups.startTool();
        history.replaceState(null, "", location.pathname + location.search + formatHash(creds));
        this.setStatus(`Uploaded ${file.name}: ${r.info!.vertices.toLocaleString("en")} vertices${r.weldedVertices ? `, ${r.weldedVertices} welded` : ""}`);
      });
    } catch (e) {
      // The current session stays on screen (load() only switches after the new mesh parsed), and
      // so does its status line, not "Uploading …".
      this.banner.status(before || "Upload failed");
      this.banner.error("Upload failed", e, "upload");
    }
  }

  private async download(format: MeshFormat, ext: string, mime: string): Promise<void> {
    const s = this.session;
    if (!s) return;
    try {
      await this.banner.progress("Preparing download…", () => downloadMesh(s.creds, s.state.revision, format, ext, mime));
    } catch (e) {
      this.fail("Download failed", e, "download");
    }
  }

  // ---------- gizmo, markers, target ghost ----------

  private wireGizmo(): void {
    const g = this.viewer.gizmo;
    g.attach(this.viewer.pivotObject);
    g.addEventListener("objectChange", () => {
      const o = this.viewer.pivotObject;
      const i = this.groups.selectedHandle();
      const c = i >= 0 ? this.session?.anchors[i]?.centroid : null;
      if (!c) return;
      // Uniform scale: take the axis the user pulled (largest change from the current scale).
      const prev = this.states[i].scale;
      const axes = [o.scale.x, o.scale.y, o.scale.z];
      let sc = axes.reduce((a, b) => (Math.abs(b - prev) > Math.abs(a - prev) ? b : a), prev);
      sc = Math.max(0.05, sc);
      o.scale.setScalar(sc);
      const q = o.quaternion;
      const st = cloneStates(this.states);
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

  /** Gizmo on the selected handle group, at pivot + translation (the centroid of its moved
   * anchors) with its R and s; a marker sphere on every other handle group. */
  private placeGizmo(): void {
    const s = this.session;
    const o = this.viewer.pivotObject;
    const i = this.groups.selectedHandle();
    const c = i >= 0 ? s?.anchors[i]?.centroid : null;
    const show = !!c && s!.role === "edit" && !s!.gone && this.groups.tool === "move" && !this.modal.active;
    this.viewer.gizmo.getHelper().visible = show;
    this.viewer.gizmo.enabled = show;
    if (c && this.states[i]) {
      const m = this.states[i];
      o.position.set(c.x + m.translation[0], c.y + m.translation[1], c.z + m.translation[2]);
      o.quaternion.set(m.rotation[1], m.rotation[2], m.rotation[3], m.rotation[0]);
      o.scale.setScalar(m.scale);
    }
    this.placeMarkers();
  }

  private placeMarkers(): void {
    const s = this.session;
    if (!s || s.role !== "edit" || s.gone || (this.groups.tool !== "move" && this.groups.tool !== "grab")) {
      this.viewer.setMarkers([]);
      return;
    }
    const sel = this.groups.selectedHandle();
    const items = [];
    for (const i of this.groups.handleIndices()) {
      const c = s.anchors[i]?.centroid;
      const t = this.states[i]?.translation;
      if (!c || !t) continue;
      items.push({ at: [c.x + t[0], c.y + t[1], c.z + t[2]] as [number, number, number], color: groupColor("handle", s.draft.ordinal(i)), selected: i === sel });
    }
    this.viewer.setMarkers(items);
  }

  /** While a move waits on a slow solve, dots show where the handle vertices are headed. */
  private scheduleTargetGhost(): void {
    clearTimeout(this.targetTimer);
    this.targetTimer = setTimeout(() => {
      const s = this.session;
      if (!s || !this.coalescer.busy) return;
      const pts: number[] = [];
      for (const i of this.groups.handleIndices()) {
        const a = s.anchors[i];
        const c = a?.centroid;
        if (!a || !c || !this.states[i]) continue;
        for (let k = 0; k < a.positions.length; k += 3) {
          pts.push(...applyMove(this.states[i], [c.x, c.y, c.z], [a.positions[k], a.positions[k + 1], a.positions[k + 2]]));
        }
      }
      this.viewer.setTargets(Float32Array.from(pts));
    }, 250);
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
