// Wiring: session lifecycle, keys and the test hooks (the G/R/S commands, the Watch worker and its
// frames on screen, the undo history, the handle groups with the tools and painting, moves with
// drags and the gizmo, file transfers, the address settings and the settings panel are in app/).
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
import { GroupSet } from "./groups";
import { parseGlb } from "./glb";
import { settingsView } from "./edit_state";
import { Timeline } from "./timeline";
import { Interaction } from "./interaction";
import { statesKey, type GroupStates } from "./moves";
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
import { MovesController } from "./app/moves_controller";
import { SettingsPanel } from "./app/settings_panel";
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
  session: Session | null = null;
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
  private sessionStatus = "";
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
    markGone: (s, detail) => this.markGone(s, detail),
    placeGizmo: () => this.moves.placeGizmo(),
  });

  readonly coalescer = new MoveCoalescer<MoveTarget, MoveHandlesResponse>({
    key: (t) => statesKey(t.states) + "|" + t.opts,
    send: (t) => this.moves.send(t),
    onResult: (r, t) => this.moves.onMoveResult(r, t),
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
    resolveWithSettings: () => this.moves.resolveWithSettings(),
    captureRevisions: () => this.history.captureRevisions(),
    historyRestarted: () => this.history.restarted(),
    undo: () => this.history.undoRedo(false),
    updateUndoButtons: () => this.history.updateButtons(),
    recolor: () => this.frames.recolor(),
    placeGizmo: () => this.moves.placeGizmo(),
  });

  private readonly moves: MovesController = new MovesController({
    banner: this.banner, timeline: this.timeline, coalescer: this.coalescer, dragToFrame: this.dragToFrame,
    session: () => this.session,
    viewer: () => this.viewer,
    interaction: () => this.interaction,
    modalActive: () => this.modal.active,
    states: () => this.states,
    setStates: (st) => { this.states = st; },
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
    fail: (prefix, e, action) => this.fail(prefix, e, action),
    optsKey: () => this.settings.optsKey(),
    currentSettings: () => this.settings.currentSettings(),
    settingsRequest: () => this.settings.request(),
    answered: (r, t) => this.history.answered(r, t),
    endCoarse: () => this.frames.endCoarse(),
    updateUndoButtons: () => this.history.updateButtons(),
    updateReady: () => this.groups.updateReady(),
    meshScale: () => this.meshScale(),
  });

  /** The state notice shown (the test hooks read it). */
  get noticeText(): string {
    return this.groups.noticeText;
  }

  start(): void {
    this.interaction = new Interaction(() => this.viewer, this.canvas, {
      tool: () => this.groups.tool,
      canEdit: () => this.canEdit(),
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
    this.moves.placeGizmo();
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
    this.moves.clearPick();
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
