// The session's lifecycle: boot from the page's link (open the session it names, or create one
// from a sample), switch the screen to a session (its mesh, settings, groups, history and Watch
// stream), reopen from an upload, close, and the ends a session can come to (a broken link, a
// session gone on the server). Also the session's buttons: Share, upload (button and drop) and
// download. Owns the open session and the session's status line.
import { Code, ConnectError } from "@connectrpc/connect";
import { HandleRole, MeshFormat, type CreateSessionResponse, type HandleGroup, type MoveHandlesResponse, type SessionInfo } from "../gen/meshdeform/v1/deformation_pb";
import type { MoveCoalescer } from "../coalescer";
import { settingsView, type SettingsView } from "../edit_state";
import { errorCode, type Action } from "../errors";
import { parseGlb } from "../glb";
import { GroupSet, type GroupSpec } from "../groups";
import { progressText, readWithProgress } from "../progress";
import type { Viewer3D } from "../scene";
import { SelectionState } from "../selection";
import { formatHash, parseLink, shareLink, type Credentials } from "../share";
import type { Hooks, Role } from "../test_hooks";
import { $, $in, type Banner } from "../ui/dom";
import { showCounts } from "../ui/metrics";
import { hideLinkProblem, showFirstHint, showLinkProblem } from "../ui/notice";
import { decoderReady, PositionState } from "../updates";
import { client, EDIT_CONTROLS, GONE_TEXT, LAMBDA, query } from "./config";
import { createSessionFromFile, downloadMesh, formatOfName } from "./mesh_files";
import type { MoveTarget, Session } from "./session";

/** What the lifecycle needs from the page. */
export interface LifecycleHost {
  readonly banner: Banner;
  readonly hooks: Hooks;
  readonly coalescer: MoveCoalescer<MoveTarget, MoveHandlesResponse>;
  viewer(): Viewer3D;
  closeModal(): void;
  /** A pick whose handles are being set is dropped. */
  clearPick(): void;
  placeGizmo(): void;
  renderGroups(): void;
  updateGroupButtons(): void;
  clearNotice(): void;
  updateReady(): void;
  setHandles(specs: GroupSpec[]): Promise<void>;
  /** The tool a session opens with (pick and drag when it has no groups). */
  startTool(): void;
  adoptGroups(groups: HandleGroup[], anchors?: number[]): void;
  anchorsAreRest(s: Session): boolean;
  /** The controls take an opened session's settings. */
  showOpened(settings: SettingsView | null, rigidity: number): void;
  showRigidity(): void;
  updateMethodAvailability(): void;
  /** The opened session's undo history, as the server keeps it. */
  restoreHistory(s: Session, info: SessionInfo, n: number): void;
  updateUndoButtons(): void;
  recolor(): void;
  startStream(s: Session, indices: Uint32Array): void;
}

export class SessionLifecycle {
  /** The open session (null before the first opens and after a broken link). */
  current: Session | null = null;
  private sessionStatus = "";

  constructor(private readonly host: LifecycleHost) {}

  canEdit(): boolean {
    const s = this.current;
    return !!s && s.role === "edit" && !s.gone && s.state.hasSnapshot;
  }

  async boot(): Promise<void> {
    const banner = this.host.banner;
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
        await banner.progress("Opening session…", () => this.openExisting(link.creds));
      } else {
        await banner.progress("Creating session…", () => this.createFromSample(query.get("sample") || "cylinder"));
        showFirstHint();
      }
    } catch (e) {
      const code = errorCode(e);
      if (link.kind === "session" && !this.current && (code === Code.NotFound || code === Code.PermissionDenied || code === Code.InvalidArgument)) {
        this.linkProblem(code === Code.NotFound ? GONE_TEXT
          : code === Code.PermissionDenied ? "The link's token does not open this session (it may be mistyped or belong to another session)."
          : "The link is malformed.");
        return;
      }
      banner.error("Could not start", e, link.kind === "session" ? "open" : "create");
      banner.status("Not connected");
    }
  }

  /** Shows the broken-link notice; nothing is created and the edit controls stay off. */
  private linkProblem(detail: string): void {
    const hooks = this.host.hooks;
    hooks.gone = true;
    hooks.ready = false;
    this.setEditEnabled(false);
    $("role").textContent = this.current ? "Session gone" : "No session";
    this.host.renderGroups();
    this.host.banner.status("No session open");
    this.host.clearNotice();
    showLinkProblem(detail, () => {
      // Same page without the fragment: a fresh demo session (the query, e.g. ?sample=, is kept).
      location.assign(location.pathname + location.search);
    });
  }

  /** The open session answered NOT_FOUND: it is gone. Stop editing and say so. */
  markGone(s: Session, detail = GONE_TEXT): void {
    if (s.gone) return;
    s.gone = true;
    s.worker?.terminate();
    s.worker = null;
    this.host.coalescer.reset();
    this.host.closeModal();
    this.linkProblem(detail);
    this.host.placeGizmo();
  }

  /** Reports a failed call in plain words; NOT_FOUND on the open session means it is gone. */
  fail(prefix: string, e: unknown, action: Action): void {
    const s = this.current;
    if (s && errorCode(e) === Code.NotFound && action !== "upload") {
      this.host.banner.error(prefix, e, action);
      this.markGone(s);
      return;
    }
    this.host.banner.error(prefix, e, action);
  }

  private async createFromSample(sample: string): Promise<void> {
    this.setStatus(`Creating session from sample “${sample}”…`);
    const r = await readWithProgress<CreateSessionResponse>(client.createSessionWithProgress({ source: { case: "sample", value: sample }, lambda: LAMBDA }), (p) =>
      this.host.banner.status(progressText(`Creating session from sample “${sample}”…`, p)),
    );
    const creds = { sessionId: r.sessionId, token: r.editToken };
    await this.load(creds, "edit", r.info!, r.viewToken, r.editToken);
    if (r.suggestedGroups.length) {
      await this.host.setHandles(r.suggestedGroups.map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" as const : "handle" as const, vertices: [...g.vertices] })));
    }
    this.host.startTool();
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
    this.host.startTool();
  }

  /** Loads faces + rest positions, switches the screen to this session, opens Watch. */
  private async load(creds: Credentials, role: Role, info: SessionInfo, viewToken: string | null, editToken: string | null): Promise<void> {
    const h = this.host;
    const hooks = h.hooks;
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
    hooks.gone = false;
    // The controls take the session's settings (those of its last move) so that a reload or a
    // shared link continues with them; a session without moves keeps the user's current choices
    // except the scale control, which starts at the session's (what its moves use unless told).
    const settings = info.edit?.settings ? settingsView(info.edit.settings) : null;
    h.showOpened(settings, info.rigidity);
    let resolveSnapshot!: () => void;
    const gotSnapshot = new Promise<void>((r) => (resolveSnapshot = r));
    const state = new PositionState(n);
    const s: Session = {
      creds, role, viewToken, editToken, indices: mesh.indices, rest: Float32Array.from(mesh.positions), restKnown,
      state, selection: new SelectionState(n), draft: new GroupSet(n), groups: [], anchors: [],
      anchorsAtRest: false, gone: false, worker: null, gotSnapshot, resolveSnapshot, heat: null, heatMetric: null, topology: null,
    };
    state.positions.set(mesh.positions);
    this.current = s;
    const viewer = h.viewer();
    viewer.setMesh(mesh.positions, mesh.indices);
    viewer.setGhost($in("ghost-rest").checked, s.rest);
    hooks.sessionId = creds.sessionId;
    hooks.role = role;
    hooks.vertexCount = n;
    hooks.revision = -1;
    this.setRole(role);
    h.showRigidity();
    showCounts(info.vertices, info.faces);
    if (settings) {
      s.selection.clear();
      s.selection.paint(settings.magnifyVertices.filter((v) => v < n), "magnify");
    }
    h.adoptGroups(info.groups, info.groupAnchors);
    // The session's undo history and the groups' current moves, as the server keeps them.
    h.restoreHistory(s, info, n);
    h.updateMethodAvailability();
    h.recolor();
    this.setStatus(`Session ${creds.sessionId.slice(0, 8)}… · ${info.vertices.toLocaleString("en")} vertices`);
    h.startStream(s, mesh.indices);
    await gotSnapshot;
    // Opened at revision 0 (the normal case for a new session): the groups' anchors are the rest pose.
    s.anchorsAtRest = (restKnown && s.state.revision === 0) || (restKnown && h.anchorsAreRest(s));
    h.updateReady();
  }

  private closeCurrent(): void {
    const s = this.current;
    if (!s) return;
    s.worker?.terminate();
    s.worker = null;
    this.current = null;
    this.host.hooks.ready = false;
    this.host.coalescer.reset();
    this.host.closeModal();
    this.host.clearPick();
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
    $in("upload-input").disabled = this.current?.role === "view";
    if (on) {
      this.host.showRigidity();
      this.host.updateMethodAvailability();
      this.host.updateUndoButtons();
      this.host.updateGroupButtons();
    }
  }

  setStatus(text: string): void {
    this.sessionStatus = text;
    this.host.banner.status(text);
  }

  // ---------- the session's buttons ----------

  /** Wires Share (and its copy buttons), upload (button and drop on the view) and download. */
  wire(): void {
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
      if (this.current?.role === "view") return;
      e.preventDefault();
      $("drop").hidden = false;
    });
    stage.addEventListener("dragleave", () => ($("drop").hidden = true));
    stage.addEventListener("drop", (e) => {
      e.preventDefault();
      $("drop").hidden = true;
      const f = e.dataTransfer?.files?.[0];
      if (f && this.current?.role !== "view") void this.upload(f);
    });
    $("download-glb").addEventListener("click", () => void this.download(MeshFormat.GLB, "glb", "model/gltf-binary"));
    $("download-obj").addEventListener("click", () => void this.download(MeshFormat.OBJ, "obj", "text/plain"));
  }

  private toggleShare(): void {
    const box = $("share-box");
    const s = this.current;
    if (!s) return;
    const base = [location.origin, location.pathname] as const;
    $in("share-view-link").value = s.viewToken ? shareLink(...base, { sessionId: s.creds.sessionId, token: s.viewToken }) : "(unknown: open the session from its creator's page)";
    $in("share-edit-link").value = s.editToken ? shareLink(...base, { sessionId: s.creds.sessionId, token: s.editToken }) : "(read-only: no edit link)";
    box.hidden = !box.hidden;
  }

  private async upload(file: File): Promise<void> {
    const banner = this.host.banner;
    const { ext, format } = formatOfName(file.name);
    if (format === null) {
      banner.message(`Upload failed: unsupported file type “.${ext}” (use .obj .off .ply .stl .glb .gltf)`);
      return;
    }
    banner.clearError();
    const before = this.sessionStatus;
    try {
      await banner.progress(`Uploading ${file.name}…`, async () => {
        const r = await createSessionFromFile(file, format, (text) => banner.status(text));
        const creds = { sessionId: r.sessionId, token: r.editToken };
        await this.load(creds, "edit", r.info!, r.viewToken, r.editToken);
        this.host.startTool();
        history.replaceState(null, "", location.pathname + location.search + formatHash(creds));
        this.setStatus(`Uploaded ${file.name}: ${r.info!.vertices.toLocaleString("en")} vertices${r.weldedVertices ? `, ${r.weldedVertices} welded` : ""}`);
      });
    } catch (e) {
      // The current session stays on screen (load() only switches after the new mesh parsed), and
      // so does its status line, not "Uploading …".
      banner.status(before || "Upload failed");
      banner.error("Upload failed", e, "upload");
    }
  }

  private async download(format: MeshFormat, ext: string, mime: string): Promise<void> {
    const s = this.current;
    if (!s) return;
    try {
      await this.host.banner.progress("Preparing download…", () => downloadMesh(s.creds, s.state.revision, format, ext, mime));
    } catch (e) {
      this.fail("Download failed", e, "download");
    }
  }
}
