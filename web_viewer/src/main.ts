// Wiring: session lifecycle, the Watch stream, moves, tools and the test hooks.
import * as THREE from "three";
import { create } from "@bufbuild/protobuf";
import { Code, ConnectError, createContextValues } from "@connectrpc/connect";
import {
  HandleGroupSchema, HandleRole, HistoryAction, MagnifyRegionSchema, MeshFormat, Method, VertexTargetsSchema,
  type CreateSessionResponse, type DeformUpdate, type HandleGroup, type MoveHandlesResponse, type SessionInfo, type SetHandlesResponse,
} from "./gen/meshdeform/v1/deformation_pb";
import { kSessionId, makeClient } from "./client";
import { progressText, readWithProgress } from "./progress";
import { MoveCoalescer } from "./coalescer";
import { rigidityLabel, rigidityStep, rigidityValue } from "./rigidity";
import { cornerAngles, faceAreas2, ramp, rampCss, scaleMax, vertexAreaLog, vertexDistortion } from "./distortion";
import { errorCode, type Action } from "./errors";
import { GroupSet, groupColor, type GroupSpec } from "./groups";
import { parseGlb } from "./glb";
import { historyFromEdit, newGesture, settingsView } from "./edit_state";
import { UndoStack } from "./history";
import { Interaction, type HandleGroupView, type Tool } from "./interaction";
import { DEFAULT_ITERATIONS, parseIterations } from "./iterations";
import { describeCommand, feedKey, startCommand, type KeyCommand } from "./keycmd";
import {
  applyMove, AXES, cloneStates, composeCommand, identityStates, planReset, statesKey, toGroupMove,
  type GroupStates, type Vec3,
} from "./moves";
import { Viewer3D } from "./scene";
import { loadPrefs, savePrefs } from "./prefs";
import { SelectionState, type PaintMode } from "./selection";
import { formatHash, parseLink, shareLink, type Credentials } from "./share";
import { Banner, $, $btn, $in, $sel } from "./ui/dom";
import { renderGroupList } from "./ui/groupsPanel";
import { showBytes, showCounts, showResult } from "./ui/metrics";
import { dismissFirstHint, hideLinkProblem, showFirstHint, showLinkProblem } from "./ui/notice";
import { decoderReady, encodingName, parseEncoding, PositionState, updateWireBytes } from "./updates";
import { linkSizedOptions, parseLinkSized } from "./update_codec";
import "./style.css";

type Role = "edit" | "view";

interface Hooks {
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
  /** Screen point of the selected handle group's centre (else the first handle group's). */
  handleScreenPoint(): { x: number; y: number } | null;
  /** Screen point of group i's centre as rendered, or of vertex v. */
  groupScreenPoint(i: number): { x: number; y: number } | null;
  vertexScreenPoint(v: number): { x: number; y: number } | null;
  worldScreenPoint(x: number, y: number, z: number): { x: number; y: number } | null;
  positions(): number[];
  /** The rest mesh (revision 0) as loaded. */
  restPositions(): number[];
  /** renderedAt / renderedRefinement / renderedConverged: per rendered update, performance.now() when it was applied and
   * whether it was a background refinement revision and converged (how a big mesh's full-resolution result arrives). */
  metrics(): {
    dragToFrameMs: number[]; updateBytes: number[]; updateEncodings: string[]; updatesRendered: number; frameWorkMs: number[];
    renderedAt: number[]; renderedRefinement: boolean[]; renderedConverged: boolean[];
  };
  resetMetrics(): void;
  /** Every applied group's move as the page holds it (translation, rotation w x y z, scale). */
  moveStates(): { translation: number[]; rotation: number[]; scale: number }[];
  /** The session's handle groups as applied (role 'fixed' | 'handle'), for tests. */
  groups(): { role: "fixed" | "handle"; vertices: number[] }[];
}

interface MoveTarget {
  states: GroupStates;
  t0: number;
  opts: string;
  /** Reset to rest: identity moves solved with the Laplacian method (see planReset). */
  reset: boolean;
  /** UNSPECIFIED records `states` in the server's history; UNDO / REDO apply its steps. */
  history: HistoryAction;
  /** The drag this move belongs to (its moves make one undo step); 0n: a step of its own. */
  gesture: bigint;
}

/** Per applied group: where its vertices were when the handles were set (the server's anchors, as
 * rendered) and their centroid (the pivot of the group's rotation and scale). */
interface Anchor {
  centroid: THREE.Vector3 | null;
  positions: Float32Array;
}

const query = new URLSearchParams(location.search);
/** localStorage, or null where the browser refuses it (privacy settings, sandboxed frames). */
function storage(): Storage | null {
  try {
    return window.localStorage;
  } catch {
    return null;
  }
}

/** The centroid of 3-per-vertex rows, or null for none. */
function centroidOfRows(a: Float32Array): THREE.Vector3 | null {
  const n = a.length / 3;
  if (n === 0) return null;
  const c = new THREE.Vector3();
  for (let k = 0; k < n; k++) c.add(new THREE.Vector3(a[k * 3], a[k * 3 + 1], a[k * 3 + 2]));
  return c.divideScalar(n);
}
const ENCODING = parseEncoding(query.get("encoding"));
// ?updates=quantized|lossless[&tolerance=X][&budget=BYTES]: link-sized Watch updates (issue 45).
const UPDATES = linkSizedOptions(parseLinkSized(query));
const client = makeClient(location.origin);
// ?lambda= soft handle weight for new sessions (server default 100 lets fixed vertices drift ~1e-4).
const LAMBDA = Number(query.get("lambda")) > 0 ? Number(query.get("lambda")) : undefined;
const FORMATS: Record<string, MeshFormat> = {
  obj: MeshFormat.OBJ, off: MeshFormat.OFF, ply: MeshFormat.PLY, stl: MeshFormat.STL, glb: MeshFormat.GLB, gltf: MeshFormat.GLTF,
};
const COLORS = { base: [0.78, 0.8, 0.84], magnify: [0.25, 0.68, 0.42] };
/** Controls that edit the session (disabled for watchers and once the session is gone). */
const EDIT_CONTROLS = ["tool-move", "tool-brush", "tool-lasso", "gizmo-translate", "gizmo-rotate", "gizmo-scale", "apply-handles", "clear-selection", "extend-group", "paint-mode",
  "undo", "redo", "method", "ora", "rigidity", "iterations", "magnify", "delete-group", "reset-rest"];
const GONE_TEXT = "The session this link points to no longer exists: it was closed, it expired, or the server restarted. Its edits cannot be recovered from here.";

/** Everything that belongs to one open session. */
interface Session {
  creds: Credentials;
  role: Role;
  viewToken: string | null;
  editToken: string | null;
  indices: Uint32Array;
  restAngles: Float32Array;
  restAreas2: Float64Array;
  /** Revision 0 as loaded; restKnown false if the server no longer had it (then it is the shape at opening). */
  rest: Float32Array;
  restKnown: boolean;
  state: PositionState;
  selection: SelectionState; // the magnify region
  draft: GroupSet; // the groups as painted
  groups: HandleGroup[]; // the groups as applied (SetHandles)
  anchors: Anchor[];
  /** The applied groups' anchors are the rest positions: identity moves give the rest pose. */
  anchorsAtRest: boolean;
  /** The last move sent (or the shape at opening) is the rest pose. */
  shapeAtRest: boolean;
  gone: boolean;
  watchGen: number;
  watchAbort: AbortController | null;
  gotSnapshot: Promise<void>;
  resolveSnapshot: () => void;
}

class App {
  readonly banner = new Banner((t) => (hooks.lastError = t));
  readonly canvas = $("canvas") as HTMLCanvasElement;
  viewer!: Viewer3D;
  interaction!: Interaction;
  session: Session | null = null;
  tool: Tool = "move";
  /** Every applied group's move (identity for fixed groups), absolute from its anchors. */
  states: GroupStates = [];
  history = new UndoStack<GroupStates>([]);
  dirty = false; // the painted groups differ from the applied ones
  private keyCmd: KeyCommand | null = null;
  private iterationsValue = DEFAULT_ITERATIONS;
  private sessionStatus = "";
  private targetTimer: ReturnType<typeof setTimeout> | undefined;
  private watchGenCounter = 0;
  private readonly moveT0 = new Map<number, number>(); // revision -> pointer time
  private readonly frameAt = new Map<number, number>(); // revision -> end of its first frame
  readonly metrics = {
    dragToFrameMs: [] as number[], updateBytes: [] as number[], updateEncodings: [] as string[], updatesRendered: 0,
    renderedAt: [] as number[], renderedRefinement: [] as boolean[], renderedConverged: [] as boolean[],
  };

  readonly coalescer = new MoveCoalescer<MoveTarget, MoveHandlesResponse>({
    key: (t) => statesKey(t.states) + "|" + t.opts + (t.reset ? "|reset" : "") + "|" + t.history,
    send: (t) => this.sendMove(t),
    onResult: (r, t) => this.onMoveResult(r, t),
    onError: (e, t) => {
      if (t.reset && this.session) this.session.shapeAtRest = false;
      this.fail(t.reset ? "Reset failed" : "Move failed", e, t.reset ? "reset" : "move");
    },
  });

  start(): void {
    this.interaction = new Interaction(() => this.viewer, this.canvas, {
      tool: () => this.tool,
      canEdit: () => this.canEdit(),
      canMove: () => !this.dirty && !this.keyCmd,
      positions: () => this.session?.state.positions ?? null,
      handleGroups: () => this.handleGroupViews(),
      groupOf: (v) => this.session?.draft.groupOf(v) ?? -1,
      select: (g) => this.selectGroup(g),
      dragStart: (g) => this.dragStart(g),
      dragMove: (d, t0) => this.dragMove(d, t0),
      dragEnd: () => this.dragEnd(),
      paintStart: (extend) => this.paintStart(extend),
      paint: (ix) => this.paint(ix),
      paintEnd: () => this.paintEnd(),
      brushRadius: () => Number($in("brush-radius").value) * this.meshScale(),
    }, $("lasso-line") as unknown as SVGPolylineElement);
    this.viewer = new Viewer3D(this.canvas, () => this.interaction.attach());
    this.wireGizmo();
    this.wireControls();
    $("legend-bar").style.background = rampCss();
    void this.boot();
  }

  private canEdit(): boolean {
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
    hooks.gone = true;
    hooks.ready = false;
    this.setEditEnabled(false);
    $("role").textContent = this.session ? "Session gone" : "No session";
    this.renderGroups();
    this.banner.status("No session open");
    showLinkProblem(detail, () => {
      // Same page without the fragment: a fresh demo session (the query, e.g. ?sample=, is kept).
      location.assign(location.pathname + location.search);
    });
  }

  /** The open session answered NOT_FOUND: it is gone. Stop editing and say so. */
  private markGone(s: Session, detail = GONE_TEXT): void {
    if (s.gone) return;
    s.gone = true;
    s.watchGen = -1;
    s.watchAbort?.abort();
    this.coalescer.reset();
    this.cancelKeyCommand();
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
      await this.setHandles(r.suggestedGroups);
    }
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
    hooks.gone = false;
    // The controls take the session's settings (those of its last move) so that a reload or a
    // shared link continues with them; a session without moves keeps the user's current choices
    // except the scale control, which starts at the session's (what its moves use unless told).
    const settings = info.edit?.settings ? settingsView(info.edit.settings) : null;
    $in("rigidity").value = String(rigidityStep(settings?.rigidity ?? info.rigidity));
    if (settings) {
      $sel("method").value = String(settings.method);
      $in("ora").checked = settings.ora;
      $in("iterations").value = String(settings.iterations);
      this.iterationsValue = settings.iterations;
      $in("magnify").value = String(settings.magnifyScale);
      $("magnify-val").textContent = settings.magnifyScale.toFixed(2);
    }
    let resolveSnapshot!: () => void;
    const gotSnapshot = new Promise<void>((r) => (resolveSnapshot = r));
    const state = new PositionState(n);
    const s: Session = {
      creds, role, viewToken, editToken, indices: mesh.indices, restAngles: cornerAngles(mesh.positions, mesh.indices),
      restAreas2: faceAreas2(mesh.positions, mesh.indices), rest: Float32Array.from(mesh.positions), restKnown,
      state, selection: new SelectionState(n), draft: new GroupSet(n), groups: [], anchors: [],
      anchorsAtRest: false, shapeAtRest: false, gone: false,
      watchGen: ++this.watchGenCounter, watchAbort: null, gotSnapshot, resolveSnapshot,
    };
    state.positions.set(mesh.positions);
    this.session = s;
    this.viewer.setMesh(mesh.positions, mesh.indices);
    this.viewer.setGhost($in("ghost-rest").checked, s.rest);
    hooks.sessionId = creds.sessionId;
    hooks.role = role;
    hooks.vertexCount = n;
    hooks.revision = -1;
    this.setRole(role);
    this.showRigidity();
    showCounts(info.vertices, info.faces);
    if (settings) {
      s.selection.clear();
      s.selection.paint(settings.magnifyVertices.filter((v) => v < n), "magnify");
    }
    this.adoptGroups(info.groups, info.groupAnchors);
    this.resetMoves();
    // The session's undo history and the groups' current moves, as the server keeps them.
    const restored = historyFromEdit(info.edit, s.anchors.map((a) => (a.centroid ? (a.centroid.toArray() as Vec3) : null)));
    this.history.restore(restored.states, restored.index);
    this.states = cloneStates(this.history.current);
    this.updateUndoButtons();
    this.updateMethodAvailability();
    this.recolor();
    this.setStatus(`Session ${creds.sessionId.slice(0, 8)}… · ${info.vertices.toLocaleString("en")} vertices`);
    void this.watchLoop(s, s.watchGen);
    await gotSnapshot;
    // Opened at revision 0 (the normal case for a new session): the groups' anchors are the rest pose.
    s.shapeAtRest = restKnown && s.state.revision === 0;
    s.anchorsAtRest = s.shapeAtRest || (restKnown && this.anchorsAreRest(s));
    this.updateReady();
  }

  private closeCurrent(): void {
    const s = this.session;
    if (!s) return;
    s.watchGen = -1;
    s.watchAbort?.abort();
    this.session = null;
    hooks.ready = false;
    this.coalescer.reset();
    this.cancelKeyCommand();
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
      this.showRigidity();
      this.updateMethodAvailability();
      this.updateUndoButtons();
      this.updateGroupButtons();
    }
  }

  private setStatus(text: string): void {
    this.sessionStatus = text;
    this.banner.status(text);
  }

  private updateReady(): void {
    const s = this.session;
    hooks.ready = !!s && !s.gone && s.state.hasSnapshot && this.handleIndices().length > 0;
    const hint = $("hint");
    if (s && s.role === "edit" && !s.gone && this.handleIndices().length === 0) {
      hint.textContent = "Paint a fixed region and a handle, then Apply.";
      hint.hidden = false;
      if (this.tool === "move") this.setTool("brush");
    } else if (s && s.role === "edit" && this.dirty) {
      hint.textContent = "The painted groups are not applied yet: Apply handles (or switch to Move) to drag them.";
      hint.hidden = false;
    } else {
      hint.hidden = true;
    }
    this.updateGroupButtons();
    this.placeGizmo();
  }

  // ---------- handle groups ----------

  /** Indices (into the applied groups) of the HANDLE groups. */
  private handleIndices(): number[] {
    const out: number[] = [];
    this.session?.groups.forEach((g, i) => { if (g.role === HandleRole.HANDLE) out.push(i); });
    return out;
  }

  private isHandle(i: number): boolean {
    return this.session?.groups[i]?.role === HandleRole.HANDLE;
  }

  /** The selected group if it is an applied handle group (moves, gizmo, G/R/S), else -1. */
  private selectedHandle(): number {
    const s = this.session;
    if (!s || this.dirty) return -1;
    const i = s.draft.selected;
    return this.isHandle(i) ? i : -1;
  }

  /** Adopts the applied groups; their anchors are `anchors` (the server's, 3 per vertex in group
   * order) when given, else the positions on screen (right after SetHandles they are the same). */
  private adoptGroups(groups: HandleGroup[], anchors?: number[]): void {
    const s = this.session!;
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
  private anchorsAreRest(s: Session): boolean {
    const tol = 1e-6 * Math.max(this.meshScale(), 1e-12);
    return s.groups.every((g, i) => g.vertices.every((v, k) =>
      [0, 1, 2].every((c) => Math.abs(s.anchors[i].positions[k * 3 + c] - s.rest[v * 3 + c]) <= tol)));
  }

  private appliedSpecs(): GroupSpec[] {
    return (this.session?.groups ?? []).map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" : "handle", vertices: [...g.vertices] }));
  }

  private async setHandles(groups: HandleGroup[]): Promise<void> {
    const s = this.session!;
    await this.coalescer.idle();
    await this.banner.progress("Factorizing…", async () => {
      this.banner.status("Factorizing…");
      const t = performance.now();
      // The streaming form reports the precompute's phases (seconds on a big mesh).
      const r = await readWithProgress<SetHandlesResponse>(
        client.setHandlesWithProgress(
          { sessionId: s.creds.sessionId, token: s.creds.token, groups, prepare: this.method() },
          { contextValues: createContextValues().set(kSessionId, s.creds.sessionId) },
        ),
        (p) => this.banner.status(progressText("Factorizing…", p)),
      );
      const nh = groups.filter((g) => g.role === HandleRole.HANDLE).length;
      this.setStatus(`Handles set (${nh} handle group${nh === 1 ? "" : "s"}, ${groups.length - nh} fixed) in ${((performance.now() - t) / 1000).toFixed(2)} s — drag the orange handle`);
      s.anchorsAtRest = s.shapeAtRest;
      this.adoptGroups(r.info?.groups.length ? r.info.groups : groups);
    });
    this.resetMoves();
    this.recolor();
    this.updateReady();
    if (this.tool !== "move") this.setTool("move");
  }

  /** Sends the painted groups (SetHandles). Returns false if they are not valid or the call failed. */
  private async applyHandles(): Promise<boolean> {
    const s = this.session;
    if (!s || s.role !== "edit" || s.gone) return false;
    const msg = s.draft.validate();
    if (msg) {
      this.banner.message(msg);
      return false;
    }
    this.banner.clearError();
    const groups = s.draft.specs().map((g) => create(HandleGroupSchema, { role: g.role === "fixed" ? HandleRole.FIXED : HandleRole.HANDLE, vertices: g.vertices }));
    try {
      await this.setHandles(groups);
      return true;
    } catch (e) {
      this.fail("Apply handles failed", e, "handles");
      return false;
    }
  }

  private selectGroup(i: number): void {
    const s = this.session;
    if (!s) return;
    s.draft.select(i);
    this.renderGroups();
    this.recolor();
    this.placeGizmo();
  }

  private async deleteGroup(i: number): Promise<void> {
    const s = this.session;
    if (!s || s.role !== "edit" || s.gone || i < 0 || i >= s.draft.size) return;
    s.draft.delete(i);
    this.afterDraftChange();
    // Deleting takes effect at once when the rest is a valid set; else it waits for more painting.
    if (!s.draft.validate()) await this.applyHandles();
    else this.banner.message(`${s.draft.validate()} The deleted group is still applied until then.`);
  }

  private afterDraftChange(): void {
    const s = this.session;
    if (!s) return;
    this.dirty = !s.draft.equals(this.appliedSpecs());
    this.renderGroups();
    this.recolor();
    this.updateReady();
  }

  private renderGroups(): void {
    const s = this.session;
    const editable = !!s && s.role === "edit" && !s.gone;
    renderGroupList(s?.draft ?? null, this.dirty, editable, { select: (i) => this.selectGroup(i), remove: (i) => void this.deleteGroup(i) });
    hooks.selectedGroup = s?.draft.selected ?? -1;
    this.updateGroupButtons();
  }

  private updateGroupButtons(): void {
    const s = this.session;
    const edit = !!s && s.role === "edit" && !s.gone;
    $btn("delete-group").disabled = !edit || s!.draft.selected < 0;
    const plan = s ? planReset(s.restKnown, s.anchorsAtRest) : "unavailable";
    $btn("reset-rest").disabled = !edit || this.handleIndices().length === 0 || plan === "unavailable";
    $btn("reset-rest").title = plan === "unavailable"
      ? "The server no longer keeps this session's rest mesh (revision 0), so the rest pose is unknown here."
      : "Every handle back to its rest position; the mesh returns to the rest pose (undoable)";
  }

  private resetMoves(): void {
    const n = this.session?.groups.length ?? 0;
    this.states = identityStates(n);
    this.history.reset(identityStates(n));
    this.coalescer.reset();
    this.updateUndoButtons();
  }

  private centroidOf(vs: ArrayLike<number>): THREE.Vector3 | null {
    const p = this.session?.state.positions;
    if (!p || vs.length === 0) return null;
    const c = new THREE.Vector3();
    for (let k = 0; k < vs.length; k++) c.add(new THREE.Vector3(p[vs[k] * 3], p[vs[k] * 3 + 1], p[vs[k] * 3 + 2]));
    return c.divideScalar(vs.length);
  }

  /** The applied handle groups with their rendered centroids, the selected one first. */
  private handleGroupViews(): HandleGroupView[] {
    const s = this.session;
    if (!s) return [];
    const sel = this.selectedHandle();
    const idx = this.handleIndices().sort((a, b) => (a === sel ? -1 : b === sel ? 1 : a - b));
    return idx.map((i) => ({ index: i, vertices: s.groups[i].vertices, centroid: this.centroidOf(s.groups[i].vertices) }));
  }

  // ---------- moves ----------

  private method(): Method {
    return Number($sel("method").value) as Method;
  }

  private optsKey(): string {
    return [$sel("method").value, $in("ora").checked, this.rigidity(), this.iterationsValue, $in("magnify").value, this.session?.selection.magnifyIndices().length ?? 0].join("|");
  }

  private rigidity(): number {
    return rigidityValue(Number($in("rigidity").value));
  }

  private showRigidity(): void {
    $("rigidity-val").textContent = rigidityLabel(this.rigidity());
    // Only the scale-aware method has a scale term.
    $in("rigidity").disabled =
      this.method() !== Method.SCALE_AWARE || this.session?.role !== "edit" || !!this.session?.gone;
  }

  /** ARAP and Laplacian cannot magnify (the server refuses regions with them): while a magnify
   * region exists they are disabled, and while one of them is chosen the magnify mode is. */
  private updateMethodAvailability(): void {
    const mag = !!this.session?.selection.hasMagnify;
    const why = "Only the scale-aware method can magnify: erase the magnify region (Brush, mode erase) to use ARAP or Laplacian.";
    for (const opt of Array.from($sel("method").options)) {
      if (opt.value === String(Method.SCALE_AWARE)) continue;
      opt.disabled = mag;
      opt.title = mag ? why : "";
    }
    $sel("method").title = mag ? why : "";
    $("method-note").textContent = mag ? "ARAP and Laplacian are off while a magnify region exists (only scale-aware can magnify)." : "";
    $("method-note").hidden = !mag;
    const scaleAware = this.method() === Method.SCALE_AWARE;
    const magOpt = Array.from($sel("paint-mode").options).find((o) => o.value === "magnify")!;
    magOpt.disabled = !scaleAware;
    magOpt.title = scaleAware ? "" : "Magnify regions need the scale-aware method.";
    if (!scaleAware && $sel("paint-mode").value === "magnify") $sel("paint-mode").value = "handle";
  }

  private submitMove(states: GroupStates, t0: number, force = false, reset = false,
    history: HistoryAction = HistoryAction.UNSPECIFIED, gesture = 0n): void {
    const s = this.session;
    if (!s || s.gone || this.handleIndices().length === 0 || s.role !== "edit") return;
    this.states = cloneStates(states);
    s.shapeAtRest = reset;
    // Undo and redo must each reach the server (its history moves one step per call).
    const barrier = history !== HistoryAction.UNSPECIFIED;
    this.coalescer.submit({ states: cloneStates(states), t0, opts: this.optsKey(), reset, history, gesture }, force, barrier);
    this.scheduleTargetGhost();
  }

  private sendMove(t: MoveTarget): Promise<MoveHandlesResponse> {
    const s = this.session!;
    const mag = t.reset ? [] : s.selection.magnifyIndices();
    // Every handle group, every time: moves are absolute, so the others keep their targets.
    // Undo / redo send none: the server applies its history's step.
    const moves = t.history !== HistoryAction.UNSPECIFIED ? [] : this.handleIndices().map((i) => {
      const c = s.anchors[i]?.centroid ?? new THREE.Vector3();
      return toGroupMove(i, t.states[i], [c.x, c.y, c.z]);
    });
    return client.moveHandles(
      {
        sessionId: s.creds.sessionId,
        token: s.creds.token,
        moves,
        // Reset: one direct Laplacian solve, no warm start from the deformed shape, so the rest
        // targets give the rest mesh itself (an iterative method would stop near it).
        method: t.reset ? Method.LAPLACIAN : this.method(),
        ora: t.reset ? false : $in("ora").checked,
        rigidity: this.rigidity(),
        maxIterations: t.reset ? 1 : this.iterationsValue,
        encoding: ENCODING,
        omitPositions: UPDATES !== undefined, // geometry comes from Watch only
        editor: t.reset ? "web-viewer reset" : "web-viewer",
        history: t.history,
        gesture: t.gesture,
        // The reset's Laplacian solve is a means, not the user's choice of method.
        keepSettings: t.reset,
        magnify: mag.length ? [create(MagnifyRegionSchema, { vertices: mag, scale: Number($in("magnify").value) })] : [],
      },
      { timeoutMs: 60_000 },
    );
  }

  private onMoveResult(r: MoveHandlesResponse, t: MoveTarget): void {
    // Geometry comes from Watch only (in order); the response is for flow control and latency.
    const rev = Number(r.result?.revision ?? -1);
    if (rev < 0) return;
    const done = this.frameAt.get(rev);
    if (done !== undefined) {
      this.metrics.dragToFrameMs.push(done - t.t0);
      this.frameAt.delete(rev);
    } else if (rev > (this.session?.state.revision ?? -1)) {
      this.moveT0.set(rev, t.t0);
    }
  }

  private dragBase: GroupStates = [];
  private dragGroup = -1;
  private dragGesture = 0n;
  private gizmoGesture = 0n;
  private dragStart(group: number): void {
    this.dragBase = cloneStates(this.states);
    this.dragGroup = group;
    this.dragGesture = newGesture();
    dismissFirstHint();
  }
  private dragMove(delta: THREE.Vector3, t0: number): void {
    const i = this.dragGroup;
    if (!this.isHandle(i)) return;
    const st = cloneStates(this.dragBase);
    const b = this.dragBase[i].translation;
    st[i].translation = [b[0] + delta.x, b[1] + delta.y, b[2] + delta.z];
    this.submitMove(st, t0, false, false, HistoryAction.UNSPECIFIED, this.dragGesture);
    this.placeGizmo();
  }
  private dragEnd(): void {
    this.history.push(cloneStates(this.states));
    this.updateUndoButtons();
  }

  // ---------- reset, numeric entry ----------

  /** Every handle back to its rest position, the mesh back to the rest pose (see planReset). */
  private async resetToRest(): Promise<void> {
    const s = this.session;
    if (!s || s.role !== "edit" || s.gone || this.handleIndices().length === 0) return;
    if (this.dirty && !(await this.applyHandles())) return;
    $in("magnify").value = "1";
    $("magnify-val").textContent = "1.00";
    const plan = planReset(s.restKnown, s.anchorsAtRest);
    if (plan === "unavailable") {
      this.banner.message("Reset is not possible: the server no longer keeps this session's rest mesh.");
      return;
    }
    if (plan === "identity") {
      const id = identityStates(s.groups.length);
      this.submitMove(id, performance.now(), true, true);
      this.history.push(cloneStates(id));
      this.updateUndoButtons();
      this.placeGizmo();
      this.banner.status("Reset to rest");
      return;
    }
    // The anchors are a deformed shape: send every constrained vertex to its rest position as one
    // temporary handle group, then set the real groups again there (anchors = rest).
    const groups = s.groups.map((g) => create(HandleGroupSchema, { role: g.role, vertices: [...g.vertices] }));
    const all = [...new Set(groups.flatMap((g) => g.vertices))].sort((a, b) => a - b);
    const positions: number[] = [];
    for (const v of all) positions.push(s.rest[v * 3], s.rest[v * 3 + 1], s.rest[v * 3 + 2]);
    try {
      await this.coalescer.idle();
      await this.banner.progress("Resetting to rest…", async () => {
        const opts = { sessionId: s.creds.sessionId, token: s.creds.token };
        await client.setHandles({ ...opts, groups: [create(HandleGroupSchema, { role: HandleRole.HANDLE, vertices: all })], prepare: Method.LAPLACIAN });
        await client.moveHandles({
          ...opts, method: Method.LAPLACIAN, maxIterations: 1, encoding: ENCODING, editor: "web-viewer reset", keepSettings: true,
          targets: create(VertexTargetsSchema, { vertices: all, positions }),
        }, { timeoutMs: 60_000 });
        s.shapeAtRest = true;
        // The positions on screen become the anchors: wait for the reset revision to arrive.
        await this.waitForShape(s, all, positions);
        await this.setHandles(groups);
      });
      this.banner.status("Reset to rest");
    } catch (e) {
      this.fail("Reset failed", e, "reset");
      s.shapeAtRest = false;
      // Put the real groups back if the temporary one is still set.
      if (!s.gone) await this.setHandles(groups).catch(() => undefined);
    }
  }

  /** Resolves once the rendered vertices `vs` are at `target` (bounded: 10 s). */
  private waitForShape(s: Session, vs: number[], target: number[]): Promise<void> {
    const scale = this.meshScale();
    const at = () => vs.every((v, k) => Math.abs(s.state.positions[v * 3] - target[k * 3]) + Math.abs(s.state.positions[v * 3 + 1] - target[k * 3 + 1]) + Math.abs(s.state.positions[v * 3 + 2] - target[k * 3 + 2]) <= 1e-4 * scale);
    return new Promise((resolve) => {
      const t0 = performance.now();
      const tick = () => (at() || performance.now() - t0 > 10_000 || s.gone ? resolve() : setTimeout(tick, 30));
      tick();
    });
  }

  private startKeyCommand(key: string): boolean {
    const cmd = startCommand(key);
    if (!cmd) return false;
    if (this.selectedHandle() < 0) {
      this.banner.message(this.dirty ? "Apply the painted groups first, then select a handle group." : "Select a handle group first (click it, or pick it in the Groups list).");
      return true;
    }
    this.keyCmd = cmd;
    this.setGizmoMode(cmd.kind);
    this.showKeyCommand();
    return true;
  }

  private feedKeyCommand(key: string): void {
    if (!this.keyCmd) return;
    const step = feedKey(this.keyCmd, key);
    if (step.state === "cancel") {
      this.cancelKeyCommand();
      return;
    }
    if (step.state === "editing") {
      this.keyCmd = step.cmd;
      if (step.cmd.kind !== this.viewer.gizmo.mode) this.setGizmoMode(step.cmd.kind);
      this.showKeyCommand();
      return;
    }
    this.cancelKeyCommand();
    const r = step.resolved;
    const i = this.selectedHandle();
    if (!r.ok || i < 0) return;
    // No axis (rotate only): about the line of sight, counter-clockwise as seen on screen.
    const axis: Vec3 = r.axis ? AXES[r.axis] : (this.viewer.viewDirection().negate().toArray() as Vec3);
    const st = cloneStates(this.states);
    st[i] = composeCommand(st[i], r.kind, axis, r.value);
    this.submitMove(st, performance.now());
    this.history.push(cloneStates(st));
    this.updateUndoButtons();
    this.placeGizmo();
  }

  private cancelKeyCommand(): void {
    this.keyCmd = null;
    $("keycmd").hidden = true;
  }

  private showKeyCommand(): void {
    $("keycmd").textContent = this.keyCmd ? describeCommand(this.keyCmd) : "";
    $("keycmd").hidden = !this.keyCmd;
  }

  // ---------- gizmo, markers, target ghost ----------

  private wireGizmo(): void {
    const g = this.viewer.gizmo;
    g.attach(this.viewer.pivotObject);
    g.addEventListener("objectChange", () => {
      const o = this.viewer.pivotObject;
      const i = this.selectedHandle();
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
      this.submitMove(st, performance.now(), false, false, HistoryAction.UNSPECIFIED, this.gizmoGesture);
      this.placeMarkers();
    });
    g.addEventListener("dragging-changed", (e: any) => {
      if (e.value) {
        this.gizmoGesture = newGesture();
        dismissFirstHint();
      } else {
        this.gizmoGesture = 0n;
        this.dragEnd();
      }
    });
  }

  /** Gizmo on the selected handle group, at pivot + translation (the centroid of its moved
   * anchors) with its R and s; a marker sphere on every other handle group. */
  private placeGizmo(): void {
    const s = this.session;
    const o = this.viewer.pivotObject;
    const i = this.selectedHandle();
    const c = i >= 0 ? s?.anchors[i]?.centroid : null;
    const show = !!c && s!.role === "edit" && !s!.gone && this.tool === "move";
    this.viewer.gizmo.getHelper().visible = show;
    this.viewer.gizmo.enabled = show;
    if (c) {
      const m = this.states[i];
      o.position.set(c.x + m.translation[0], c.y + m.translation[1], c.z + m.translation[2]);
      o.quaternion.set(m.rotation[1], m.rotation[2], m.rotation[3], m.rotation[0]);
      o.scale.setScalar(m.scale);
    }
    this.placeMarkers();
  }

  private placeMarkers(): void {
    const s = this.session;
    if (!s || s.role !== "edit" || s.gone || this.tool !== "move") {
      this.viewer.setMarkers([]);
      return;
    }
    const sel = this.selectedHandle();
    const items = [];
    for (const i of this.handleIndices()) {
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
      for (const i of this.handleIndices()) {
        const a = s.anchors[i];
        const c = a?.centroid;
        if (!a || !c) continue;
        for (let k = 0; k < a.positions.length; k += 3) {
          pts.push(...applyMove(this.states[i], [c.x, c.y, c.z], [a.positions[k], a.positions[k + 1], a.positions[k + 2]]));
        }
      }
      this.viewer.setTargets(Float32Array.from(pts));
    }, 250);
  }

  // ---------- Watch ----------

  private async watchLoop(s: Session, gen: number): Promise<void> {
    let backoff = 250;
    while (s.watchGen === gen) {
      const ac = new AbortController();
      s.watchAbort = ac;
      try {
        const stream = client.watch(
          { sessionId: s.creds.sessionId, token: s.creds.token, encoding: ENCODING, updates: UPDATES },
          { signal: ac.signal, contextValues: createContextValues().set(kSessionId, s.creds.sessionId) },
        );
        for await (const upd of stream) {
          if (s.watchGen !== gen) return;
          backoff = 250;
          this.onUpdate(s, upd);
        }
        if (s.watchGen === gen) {
          // Ends OK only when the session is closed: nothing to reconnect to, nothing to edit.
          s.resolveSnapshot();
          this.markGone(s, "The session was closed by its owner (or an operator). Its link no longer opens it.");
        }
        return;
      } catch (e) {
        if (s.watchGen !== gen) return;
        const code = ConnectError.from(e).code;
        if (code === Code.NotFound) {
          s.resolveSnapshot();
          this.markGone(s);
          return;
        }
        if (code === Code.PermissionDenied || code === Code.InvalidArgument) {
          this.banner.error("Watching the session failed", e, "watch");
          hooks.ready = false;
          s.resolveSnapshot();
          return;
        }
        this.banner.status(`Connection lost — reconnecting in ${(backoff / 1000).toFixed(1)} s`);
        await new Promise((r) => setTimeout(r, backoff));
        backoff = Math.min(backoff * 2, 10_000);
      }
    }
  }

  private onUpdate(s: Session, upd: DeformUpdate): void {
    const bytes = updateWireBytes(upd);
    const r = upd.result!;
    this.metrics.updateBytes.push(bytes);
    this.metrics.updateEncodings.push(encodingName(r.encoding));
    showBytes(bytes, encodingName(r.encoding));
    let applied;
    try {
      applied = s.state.apply(upd);
    } catch (e) {
      this.banner.error("Bad update from the server", e);
      return;
    }
    if (!applied.applied) return;
    const rev = s.state.revision;
    this.viewer.updatePositions(s.state.positions);
    if ($in("heatmap").checked) this.recolor();
    showResult(r, rev, this.interaction.dragging || this.viewer.gizmo.dragging);
    hooks.revision = rev;
    this.metrics.updatesRendered++;
    this.metrics.renderedAt.push(performance.now());
    this.metrics.renderedRefinement.push(r.refinement);
    this.metrics.renderedConverged.push(r.converged);
    if (!this.coalescer.busy) this.viewer.setTargets(null);
    if (upd.isSnapshot) s.resolveSnapshot();
    if (!this.viewer.gizmo.dragging) this.placeGizmo();
    this.viewer.onNextFrame(() => {
      const now = performance.now();
      const t0 = this.moveT0.get(rev);
      if (t0 !== undefined) {
        this.metrics.dragToFrameMs.push(now - t0);
        this.moveT0.delete(rev);
      } else {
        this.frameAt.set(rev, now);
      }
      // Bound the bookkeeping: revisions far behind will never be matched.
      for (const m of [this.frameAt, this.moveT0]) for (const k of m.keys()) if (k < rev - 64) m.delete(k);
    });
  }

  // ---------- colours ----------

  private recolor(): void {
    const s = this.session;
    if (!s) return;
    const n = s.state.vertexCount;
    const rgb = new Float32Array(n * 3);
    const heat = $in("heatmap").checked;
    $("legend").hidden = !heat;
    if (heat && $sel("heatmap-mode").value === "area") {
      // |log(area / rest area)|: scale drift, which the angle map hides by design.
      const signed = vertexAreaLog(s.restAreas2, s.state.positions, s.indices, n);
      const d = signed.map(Math.abs);
      const max = scaleMax(d, 0.01);
      $("legend-min").textContent = "×1";
      $("legend-max").textContent = `×${Math.exp(max).toFixed(2)} or ÷${Math.exp(max).toFixed(2)}`;
      $("legend-what").textContent = "face area vs rest (mean |log ratio|)";
      for (let i = 0; i < n; i++) rgb.set(ramp(d[i] / max), i * 3);
    } else if (heat) {
      const d = vertexDistortion(s.restAngles, s.state.positions, s.indices, n);
      const max = scaleMax(d, THREE.MathUtils.degToRad(0.5));
      $("legend-min").textContent = "0°";
      $("legend-max").textContent = `${THREE.MathUtils.radToDeg(max).toFixed(1)}°`;
      $("legend-what").textContent = "mean |Δ corner angle|";
      for (let i = 0; i < n; i++) rgb.set(ramp(d[i] / max), i * 3);
    } else {
      const g = s.draft;
      // Per group: its colour, lighter for the selected one.
      const palette = Array.from({ length: g.size }, (_, k) => {
        const c = groupColor(g.role(k), g.ordinal(k));
        return k === g.selected ? c.map((x) => x + (1 - x) * 0.4) : c;
      });
      for (let i = 0; i < n; i++) {
        const k = g.groupOf(i);
        const c = k >= 0 ? palette[k] : s.selection.magnify[i] ? COLORS.magnify : COLORS.base;
        rgb[i * 3] = c[0]; rgb[i * 3 + 1] = c[1]; rgb[i * 3 + 2] = c[2];
      }
    }
    this.viewer.setColors(rgb);
  }

  // ---------- painting ----------

  private paintStart(extend: boolean): void {
    const s = this.session;
    const mode = $sel("paint-mode").value as PaintMode;
    if (!s || (mode !== "fixed" && mode !== "handle")) return;
    s.draft.beginStroke(mode, extend || $in("extend-group").checked);
  }

  private paint(ix: number[]): void {
    const s = this.session;
    if (!s) return;
    const mode = $sel("paint-mode").value as PaintMode;
    if (ix.length === 0) {
      if (this.tool === "lasso") this.banner.message("The lasso selected no vertex facing the camera.");
      return;
    }
    if (mode === "fixed" || mode === "handle") s.draft.paint(ix);
    else if (mode === "erase") s.draft.erase(ix);
    s.selection.paint(ix, mode);
    if (mode === "magnify" || mode === "erase") {
      this.updateMethodAvailability();
      this.resolveWithSettings();
    }
    this.recolor();
  }

  private paintEnd(): void {
    this.session?.draft.endStroke();
    this.afterDraftChange();
  }

  private meshScale(): number {
    const bb = this.viewer.geometry?.boundingBox;
    return bb ? bb.getSize(new THREE.Vector3()).length() : 1;
  }

  // ---------- controls ----------

  private setTool(t: Tool): void {
    // Back to Move with painted changes: apply them (that is what the user wants to drag).
    if (t === "move" && this.tool !== "move" && this.dirty && this.session?.draft.validate() === null) {
      void this.applyHandles();
      return;
    }
    this.tool = t;
    for (const x of ["move", "brush", "lasso"] as const) $(`tool-${x}`).classList.toggle("on", x === t);
    $("paint-opts").hidden = t === "move";
    $("gizmo-modes").hidden = t !== "move";
    $("brush-radius-row").hidden = t !== "brush";
    this.viewer.orbit.enabled = true;
    this.placeGizmo();
  }

  private setGizmoMode(m: "translate" | "rotate" | "scale"): void {
    this.viewer.gizmo.setMode(m);
    for (const x of ["translate", "rotate", "scale"]) $(`gizmo-${x}`).classList.toggle("on", x === m);
  }

  /** A setting changed: solve again with it (the server also keeps it for the next page that
   * opens the session; an unchanged state adds no undo step). */
  private resolveWithSettings(): void {
    if (this.handleIndices().length > 0) this.submitMove(this.states, performance.now(), true);
  }

  private updateUndoButtons(): void {
    const edit = this.session?.role === "edit" && !this.session.gone;
    $btn("undo").disabled = !edit || !this.history.canUndo;
    $btn("redo").disabled = !edit || !this.history.canRedo;
  }

  private undoRedo(redo: boolean): void {
    if (this.session?.role !== "edit" || this.session.gone) return;
    const st = redo ? this.history.redo() : this.history.undo();
    if (!st) return;
    this.submitMove(st, performance.now(), true, false, redo ? HistoryAction.REDO : HistoryAction.UNDO);
    this.placeGizmo();
    this.updateUndoButtons();
  }

  /** Validates the iterations field as typed; a bad value is shown and not used. */
  private checkIterations(): boolean {
    const r = parseIterations($in("iterations").value);
    $in("iterations").classList.toggle("invalid", !r.ok);
    $in("iterations").setCustomValidity(r.ok ? "" : r.reason);
    $("iterations-note").textContent = r.ok ? "" : `${r.reason} Moves keep using ${this.iterationsValue}.`;
    $("iterations-note").hidden = r.ok;
    if (r.ok) this.iterationsValue = r.value;
    return r.ok;
  }

  private onKey(e: KeyboardEvent): void {
    const el = e.target as HTMLElement | null;
    const typing = (el?.tagName === "INPUT" && (el as HTMLInputElement).type !== "range" && (el as HTMLInputElement).type !== "checkbox") || el?.tagName === "SELECT" || el?.tagName === "TEXTAREA";
    if (typing) return;
    if (this.keyCmd && !e.ctrlKey && !e.metaKey && !e.altKey) {
      e.preventDefault();
      this.feedKeyCommand(e.key);
      return;
    }
    if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") {
      e.preventDefault();
      this.undoRedo(e.shiftKey);
    } else if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "y") {
      e.preventDefault();
      this.undoRedo(true);
    } else if (!e.ctrlKey && !e.metaKey && !e.altKey && this.canEdit()) {
      if (e.key === "Delete") {
        const i = this.session!.draft.selected;
        if (i >= 0) {
          e.preventDefault();
          void this.deleteGroup(i);
        }
      } else if (this.startKeyCommand(e.key)) {
        e.preventDefault();
      }
    }
  }

  private wireControls(): void {
    $("tool-move").addEventListener("click", () => this.setTool("move"));
    $("tool-brush").addEventListener("click", () => this.setTool("brush"));
    $("tool-lasso").addEventListener("click", () => this.setTool("lasso"));
    $("gizmo-translate").addEventListener("click", () => this.setGizmoMode("translate"));
    $("gizmo-rotate").addEventListener("click", () => this.setGizmoMode("rotate"));
    $("gizmo-scale").addEventListener("click", () => this.setGizmoMode("scale"));
    $("apply-handles").addEventListener("click", () => void this.applyHandles());
    $("clear-selection").addEventListener("click", () => {
      this.session?.selection.clear();
      this.session?.draft.clear();
      this.updateMethodAvailability();
      this.afterDraftChange();
    });
    $("delete-group").addEventListener("click", () => void this.deleteGroup(this.session?.draft.selected ?? -1));
    $("reset-rest").addEventListener("click", () => void this.resetToRest());
    const radius = () => ($("brush-radius-val").textContent = `${(Number($in("brush-radius").value) * 100).toFixed(1)}% of size`);
    $in("brush-radius").addEventListener("input", radius);
    radius();
    $in("iterations").addEventListener("input", () => this.checkIterations());
    $in("iterations").addEventListener("change", () => {
      if (this.checkIterations()) this.resolveWithSettings();
    });
    for (const id of ["method", "ora"]) $(id).addEventListener("change", () => this.resolveWithSettings());
    $in("rigidity").addEventListener("input", () => this.showRigidity());
    $in("rigidity").addEventListener("change", () => this.resolveWithSettings());  // re-solves live
    $sel("method").addEventListener("change", () => {
      this.showRigidity();
      this.updateMethodAvailability();
    });
    $in("magnify").addEventListener("input", () => ($("magnify-val").textContent = Number($in("magnify").value).toFixed(2)));
    $in("magnify").addEventListener("change", () => {
      if (this.session && !this.session.selection.hasMagnify) this.banner.message("Paint a “magnify region” first (Brush or Lasso, mode magnify region).");
      this.resolveWithSettings();
    });
    // View preferences are the person's, not the session's: kept in this browser.
    const prefs = loadPrefs(storage());
    $in("heatmap").checked = prefs.heatmap;
    $sel("heatmap-mode").value = prefs.heatmapMode;
    $in("wireframe").checked = prefs.wireframe;
    $in("ghost-rest").checked = prefs.ghost;
    this.viewer.setWireframe(prefs.wireframe);
    const keepPrefs = () => savePrefs(storage(), {
      heatmap: $in("heatmap").checked, heatmapMode: $sel("heatmap-mode").value === "area" ? "area" : "angle",
      wireframe: $in("wireframe").checked, ghost: $in("ghost-rest").checked,
    });
    for (const id of ["heatmap", "heatmap-mode", "wireframe", "ghost-rest"]) $(id).addEventListener("change", keepPrefs);
    $in("heatmap").addEventListener("change", () => this.recolor());
    $sel("heatmap-mode").addEventListener("change", () => this.recolor());
    $in("wireframe").addEventListener("change", () => this.viewer.setWireframe($in("wireframe").checked));
    $in("ghost-rest").addEventListener("change", () => this.viewer.setGhost($in("ghost-rest").checked, this.session?.rest ?? null));
    $("reset-view").addEventListener("click", () => this.viewer.frame());
    $("undo").addEventListener("click", () => this.undoRedo(false));
    $("redo").addEventListener("click", () => this.undoRedo(true));
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
    const ext = file.name.split(".").pop()?.toLowerCase() ?? "";
    const format = FORMATS[ext];
    if (!format) {
      this.banner.message(`Upload failed: unsupported file type “.${ext}” (use .obj .off .ply .stl .glb .gltf)`);
      return;
    }
    this.banner.clearError();
    const before = this.sessionStatus;
    try {
      await this.banner.progress(`Uploading ${file.name}…`, async () => {
        const bytes = new Uint8Array(await file.arrayBuffer());
        this.banner.status(`Uploading ${file.name} (${(bytes.length / 1024).toFixed(0)} KiB)…`);
        const r = await readWithProgress<CreateSessionResponse>(
          client.createSessionWithProgress({ source: { case: "meshBytes", value: bytes }, format, lambda: LAMBDA, weld: format === MeshFormat.STL || format === MeshFormat.OBJ }),
          (p) => this.banner.status(progressText(`Uploading ${file.name}…`, p)),
        );
        const creds = { sessionId: r.sessionId, token: r.editToken };
        await this.load(creds, "edit", r.info!, r.viewToken, r.editToken);
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
      const r = await this.banner.progress("Preparing download…", () =>
        client.getMesh({ sessionId: s.creds.sessionId, token: s.creds.token, format, revision: BigInt(Math.max(0, s.state.revision)) }).catch((e) => {
          if (errorCode(e) !== Code.NotFound) throw e;
          return client.getMesh({ sessionId: s.creds.sessionId, token: s.creds.token, format });
        }));
      const url = URL.createObjectURL(new Blob([r.meshBytes as BlobPart], { type: mime }));
      const a = document.createElement("a");
      a.href = url;
      a.download = `meshdeform-${s.creds.sessionId.slice(0, 8)}-r${s.state.revision}.${ext}`;
      document.body.appendChild(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(url), 10_000);
    } catch (e) {
      this.fail("Download failed", e, "download");
    }
  }

  // ---------- test hooks ----------

  screenPoint(c: THREE.Vector3 | null): { x: number; y: number } | null {
    const p = c && this.viewer.toScreen(c.x, c.y, c.z);
    return p ? { x: p[0], y: p[1] } : null;
  }

  hookHandlePoint(): { x: number; y: number } | null {
    const views = this.handleGroupViews();
    return this.screenPoint(views[0]?.centroid ?? null);
  }

  hookGroupPoint(i: number): { x: number; y: number } | null {
    const g = this.session?.groups[i];
    return g ? this.screenPoint(this.centroidOf(g.vertices)) : null;
  }

  hookVertexPoint(v: number): { x: number; y: number } | null {
    const p = this.session?.state.positions;
    return p && v >= 0 && v * 3 < p.length ? this.screenPoint(new THREE.Vector3(p[v * 3], p[v * 3 + 1], p[v * 3 + 2])) : null;
  }
}

const app = new App();
const hooks: Hooks = {
  ready: false,
  revision: -1,
  sessionId: "",
  role: "edit",
  vertexCount: 0,
  lastError: "",
  gone: false,
  selectedGroup: -1,
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
      renderedConverged: [...m.renderedConverged],
    };
  },
  moveStates() {
    return app.states.map((m) => ({ translation: [...m.translation], rotation: [...m.rotation], scale: m.scale }));
  },
  groups() {
    return (app.session?.groups ?? []).map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" as const : "handle" as const, vertices: [...g.vertices] }));
  },
  resetMetrics() {
    app.metrics.dragToFrameMs.length = 0;
    app.metrics.updateBytes.length = 0;
    app.metrics.updateEncodings.length = 0;
    app.metrics.updatesRendered = 0;
    app.metrics.renderedAt.length = 0;
    app.metrics.renderedRefinement.length = 0;
    app.metrics.renderedConverged.length = 0;
    app.viewer.frameWorkMs.length = 0;
  },
};
(window as unknown as { __meshdeform: Hooks }).__meshdeform = hooks;
app.start();
