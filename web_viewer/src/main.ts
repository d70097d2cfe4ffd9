// Wiring: session lifecycle, the Watch stream, moves, tools and the test hooks.
import * as THREE from "three";
import { create, toBinary } from "@bufbuild/protobuf";
import { Code, ConnectError, createContextValues } from "@connectrpc/connect";
import {
  DeformUpdateSchema, HandleGroupSchema, HandleRole, MagnifyRegionSchema, MeshFormat, Method,
  type DeformUpdate, type HandleGroup, type MoveHandlesResponse, type SessionInfo,
} from "./gen/meshdeform/v1/deformation_pb";
import { kSessionId, makeClient } from "./client";
import { MoveCoalescer } from "./coalescer";
import { rigidityLabel, rigidityStep, rigidityValue } from "./rigidity";
import { cornerAngles, faceAreas2, ramp, rampCss, scaleMax, vertexAreaLog, vertexDistortion } from "./distortion";
import { parseGlb } from "./glb";
import { UndoStack } from "./history";
import { Interaction, type Tool } from "./interaction";
import { cloneMove, IDENTITY, moveKey, toGroupMove, type MoveState } from "./moves";
import { Viewer3D } from "./scene";
import { SelectionState, type PaintMode } from "./selection";
import { formatHash, parseHash, shareLink, type Credentials } from "./share";
import { Banner, $, $btn, $in, $sel } from "./ui/dom";
import { showBytes, showCounts, showResult } from "./ui/metrics";
import { decoderReady, encodingName, parseEncoding, PositionState } from "./updates";
import "./style.css";

type Role = "edit" | "view";

interface Hooks {
  ready: boolean;
  revision: number;
  sessionId: string;
  role: Role;
  vertexCount: number;
  lastError: string;
  handleScreenPoint(): { x: number; y: number } | null;
  positions(): number[];
  metrics(): { dragToFrameMs: number[]; updateBytes: number[]; updateEncodings: string[]; updatesRendered: number; frameWorkMs: number[] };
  resetMetrics(): void;
  /** The session's handle groups as applied (role 'fixed' | 'handle'), for tests. */
  groups(): { role: "fixed" | "handle"; vertices: number[] }[];
}

interface MoveTarget {
  state: MoveState;
  t0: number;
  opts: string;
}

const query = new URLSearchParams(location.search);
const ENCODING = parseEncoding(query.get("encoding"));
const client = makeClient(location.origin);
// ?lambda= soft handle weight for new sessions (server default 100 lets fixed vertices drift ~1e-4).
const LAMBDA = Number(query.get("lambda")) > 0 ? Number(query.get("lambda")) : undefined;
const FORMATS: Record<string, MeshFormat> = {
  obj: MeshFormat.OBJ, off: MeshFormat.OFF, ply: MeshFormat.PLY, stl: MeshFormat.STL, glb: MeshFormat.GLB, gltf: MeshFormat.GLTF,
};
const COLORS = { base: [0.78, 0.8, 0.84], fixed: [0.22, 0.42, 0.88], handle: [0.96, 0.5, 0.14], magnify: [0.25, 0.68, 0.42] };

/** Everything that belongs to one open session. */
interface Session {
  creds: Credentials;
  role: Role;
  viewToken: string | null;
  editToken: string | null;
  indices: Uint32Array;
  restAngles: Float32Array;
  restAreas2: Float64Array;
  state: PositionState;
  selection: SelectionState;
  groups: HandleGroup[];
  handleGroup: number; // index into groups, -1 without handles
  anchorCentroid: THREE.Vector3 | null;
  watchGen: number;
  watchAbort: AbortController | null;
  gotSnapshot: Promise<void>;
  resolveSnapshot: () => void;
}

class App {
  readonly banner = new Banner((t) => (hooks.lastError = t));
  readonly canvas = $("canvas") as HTMLCanvasElement;
  viewer!: Viewer3D;
  session: Session | null = null;
  tool: Tool = "move";
  moveState: MoveState = cloneMove(IDENTITY);
  history = new UndoStack<MoveState>(cloneMove(IDENTITY));
  moved = false; // a move was sent since the handles were set
  private watchGenCounter = 0;
  private readonly moveT0 = new Map<number, number>(); // revision -> pointer time
  private readonly frameAt = new Map<number, number>(); // revision -> end of its first frame
  readonly metrics = { dragToFrameMs: [] as number[], updateBytes: [] as number[], updateEncodings: [] as string[], updatesRendered: 0 };

  readonly coalescer = new MoveCoalescer<MoveTarget, MoveHandlesResponse>({
    key: (t) => moveKey(t.state) + "|" + t.opts,
    send: (t) => this.sendMove(t),
    onResult: (r, t) => this.onMoveResult(r, t),
    onError: (e) => this.banner.error("Move failed", e),
  });

  start(): void {
    const interaction = new Interaction(() => this.viewer, this.canvas, {
      tool: () => this.tool,
      canEdit: () => this.session?.role === "edit" && this.session.state.hasSnapshot,
      positions: () => this.session?.state.positions ?? null,
      handleVertices: () => this.handleVertices(),
      handleCentroid: () => this.handleCentroid(),
      dragStart: () => this.dragStart(),
      dragMove: (d, t0) => this.dragMove(d, t0),
      dragEnd: () => this.dragEnd(),
      paint: (ix) => this.paint(ix),
      brushRadius: () => Number($in("brush-radius").value) * this.meshScale(),
    }, $("lasso-line") as unknown as SVGPolylineElement);
    this.viewer = new Viewer3D(this.canvas, () => interaction.attach());
    this.wireGizmo();
    this.wireControls();
    $("legend-bar").style.background = rampCss();
    void this.boot();
  }

  // ---------- session lifecycle ----------

  private async boot(): Promise<void> {
    try {
      await decoderReady();
      const creds = parseHash(location.hash);
      if (creds) {
        await this.banner.progress("Opening session…", () => this.openExisting(creds));
      } else {
        await this.banner.progress("Creating session…", () => this.createFromSample(query.get("sample") || "cylinder"));
      }
    } catch (e) {
      this.banner.error("Could not start", e);
      this.banner.status("Not connected");
    }
  }

  private async createFromSample(sample: string): Promise<void> {
    this.banner.status(`Creating session from sample “${sample}”…`);
    const r = await client.createSession({ source: { case: "sample", value: sample }, lambda: LAMBDA });
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
    await this.load(creds, role, info, r.canEdit ? r.viewToken : creds.token, r.canEdit ? creds.token : null);
    const s = this.session!;
    if (role === "edit" && s.handleGroup >= 0 && Number(info.revision) > 0) {
      // Anchors are the positions at the last SetHandles, which we cannot know; setting the same
      // groups again makes the current shape the anchors so the first drag does not jump.
      await s.gotSnapshot;
      await this.setHandles(info.groups);
    }
  }

  /** Loads faces + rest positions, switches the screen to this session, opens Watch. */
  private async load(creds: Credentials, role: Role, info: SessionInfo, viewToken: string | null, editToken: string | null): Promise<void> {
    // Rest mesh (revision 0) for the heat map; fall back to the current one if not kept.
    let glb;
    try {
      glb = await client.getMesh({ sessionId: creds.sessionId, token: creds.token, format: MeshFormat.GLB, revision: 0n });
    } catch (e) {
      if (ConnectError.from(e).code !== Code.NotFound) throw e;
      glb = await client.getMesh({ sessionId: creds.sessionId, token: creds.token, format: MeshFormat.GLB });
    }
    const mesh = parseGlb(glb.meshBytes);
    const n = mesh.positions.length / 3;
    if (n !== info.vertices) throw new Error(`GLB has ${n} vertices, session ${info.vertices}`);
    this.closeCurrent();
    // The slider starts at the session's scale control (what its moves use unless told).
    $in("rigidity").value = String(rigidityStep(info.rigidity));
    this.showRigidity();
    let resolveSnapshot!: () => void;
    const gotSnapshot = new Promise<void>((r) => (resolveSnapshot = r));
    const state = new PositionState(n);
    const s: Session = {
      creds, role, viewToken, editToken, indices: mesh.indices, restAngles: cornerAngles(mesh.positions, mesh.indices),
      restAreas2: faceAreas2(mesh.positions, mesh.indices),
      state, selection: new SelectionState(n), groups: [], handleGroup: -1, anchorCentroid: null,
      watchGen: ++this.watchGenCounter, watchAbort: null, gotSnapshot, resolveSnapshot,
    };
    state.positions.set(mesh.positions);
    this.session = s;
    this.viewer.setMesh(mesh.positions, mesh.indices);
    hooks.sessionId = creds.sessionId;
    hooks.role = role;
    hooks.vertexCount = n;
    hooks.revision = -1;
    this.setRole(role);
    showCounts(info.vertices, info.faces);
    this.adoptGroups(info.groups);
    this.resetMoves();
    this.recolor();
    this.banner.status(`Session ${creds.sessionId.slice(0, 8)}… · ${info.vertices.toLocaleString("en")} vertices`);
    void this.watchLoop(s, s.watchGen);
    await gotSnapshot;
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
  }

  private setRole(role: Role): void {
    document.body.classList.toggle("viewer-readonly", role === "view");
    const el = $("role");
    el.textContent = role === "view" ? "Watching (read-only)" : "Editing";
    el.classList.toggle("view", role === "view");
    this.viewer.gizmo.enabled = role === "edit";
    for (const id of ["tool-move", "tool-brush", "tool-lasso", "apply-handles", "undo", "redo", "upload-input", "method", "ora", "rigidity", "iterations", "magnify"]) {
      ($(id) as HTMLInputElement).disabled = role === "view";
    }
    this.updateUndoButtons();
  }

  private updateReady(): void {
    const s = this.session;
    hooks.ready = !!s && s.state.hasSnapshot && s.handleGroup >= 0;
    const hint = $("hint");
    if (s && s.role === "edit" && s.handleGroup < 0) {
      hint.textContent = "Paint a fixed region and a handle, then Apply.";
      hint.hidden = false;
      if (this.tool === "move") this.setTool("brush");
    } else {
      hint.hidden = true;
    }
    this.placeGizmo();
  }

  // ---------- handles ----------

  private adoptGroups(groups: HandleGroup[]): void {
    const s = this.session!;
    s.groups = groups.map((g) => create(HandleGroupSchema, { role: g.role, vertices: [...g.vertices] }));
    s.handleGroup = s.groups.findIndex((g) => g.role === HandleRole.HANDLE);
    s.selection.role.fill(0);
    for (const g of s.groups) for (const v of g.vertices) s.selection.role[v] = g.role === HandleRole.FIXED ? 1 : 2;
    s.anchorCentroid = this.centroidOf(s.handleGroup >= 0 ? s.groups[s.handleGroup].vertices : []);
  }

  private async setHandles(groups: HandleGroup[]): Promise<void> {
    const s = this.session!;
    await this.coalescer.idle();
    await this.banner.progress("Factorizing…", async () => {
      this.banner.status("Factorizing…");
      const t = performance.now();
      const r = await client.setHandles({ sessionId: s.creds.sessionId, token: s.creds.token, groups, prepare: this.method() });
      this.banner.status(`Handles set (${groups.length} groups) in ${((performance.now() - t) / 1000).toFixed(2)} s — drag the orange handle`);
      // Anchors are the positions at this call: the ones on screen now.
      this.adoptGroups(r.info?.groups.length ? r.info.groups : groups);
    });
    this.resetMoves();
    this.recolor();
    this.updateReady();
    if (this.tool !== "move") this.setTool("move");
  }

  private async applyHandles(): Promise<void> {
    const s = this.session;
    if (!s || s.role !== "edit") return;
    const msg = s.selection.validate();
    if (msg) {
      this.banner.message(msg);
      return;
    }
    this.banner.clearError();
    const groups = [
      create(HandleGroupSchema, { role: HandleRole.FIXED, vertices: s.selection.indicesWithRole(1) }),
      create(HandleGroupSchema, { role: HandleRole.HANDLE, vertices: s.selection.indicesWithRole(2) }),
    ];
    try {
      await this.setHandles(groups);
    } catch (e) {
      this.banner.error("Apply handles failed", e);
    }
  }

  private resetMoves(): void {
    this.moveState = cloneMove(IDENTITY);
    this.history.reset(cloneMove(IDENTITY));
    this.moved = false;
    this.coalescer.reset();
    this.updateUndoButtons();
  }

  private handleVertices(): number[] {
    const s = this.session;
    return s && s.handleGroup >= 0 ? s.groups[s.handleGroup].vertices : [];
  }

  private centroidOf(vs: ArrayLike<number>): THREE.Vector3 | null {
    const p = this.session?.state.positions;
    if (!p || vs.length === 0) return null;
    const c = new THREE.Vector3();
    for (let k = 0; k < vs.length; k++) c.add(new THREE.Vector3(p[vs[k] * 3], p[vs[k] * 3 + 1], p[vs[k] * 3 + 2]));
    return c.divideScalar(vs.length);
  }

  private handleCentroid(): THREE.Vector3 | null {
    return this.centroidOf(this.handleVertices());
  }

  // ---------- moves ----------

  private method(): Method {
    return Number($sel("method").value) as Method;
  }

  private optsKey(): string {
    return [$sel("method").value, $in("ora").checked, this.rigidity(), this.iterations(), $in("magnify").value, this.session?.selection.magnifyIndices().length ?? 0].join("|");
  }

  private rigidity(): number {
    return rigidityValue(Number($in("rigidity").value));
  }

  private showRigidity(): void {
    $("rigidity-val").textContent = rigidityLabel(this.rigidity());
    // Only the scale-aware method has a scale term.
    $in("rigidity").disabled =
      this.method() !== Method.SCALE_AWARE || document.body.classList.contains("viewer-readonly");
  }

  private iterations(): number {
    const n = Math.round(Number($in("iterations").value));
    return Number.isFinite(n) && n > 0 ? Math.min(1000, n) : 2;
  }

  private submitMove(state: MoveState, t0: number, force = false): void {
    if (!this.session || this.session.handleGroup < 0 || this.session.role !== "edit") return;
    this.moveState = cloneMove(state);
    this.moved = true;
    this.coalescer.submit({ state: cloneMove(state), t0, opts: this.optsKey() }, force);
  }

  private sendMove(t: MoveTarget): Promise<MoveHandlesResponse> {
    const s = this.session!;
    const pivot = s.anchorCentroid ?? new THREE.Vector3();
    const mag = s.selection.magnifyIndices();
    return client.moveHandles(
      {
        sessionId: s.creds.sessionId,
        token: s.creds.token,
        moves: [toGroupMove(s.handleGroup, t.state, [pivot.x, pivot.y, pivot.z])],
        method: this.method(),
        ora: $in("ora").checked,
        rigidity: this.rigidity(),
        maxIterations: this.iterations(),
        encoding: ENCODING,
        editor: "web-viewer",
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

  private dragBase: MoveState = cloneMove(IDENTITY);
  private dragStart(): void {
    this.dragBase = cloneMove(this.moveState);
  }
  private dragMove(delta: THREE.Vector3, t0: number): void {
    const st = cloneMove(this.dragBase);
    st.translation = [this.dragBase.translation[0] + delta.x, this.dragBase.translation[1] + delta.y, this.dragBase.translation[2] + delta.z];
    this.submitMove(st, t0);
    this.placeGizmo();
  }
  private dragEnd(): void {
    this.history.push(cloneMove(this.moveState));
    this.updateUndoButtons();
  }

  // ---------- gizmo ----------

  private wireGizmo(): void {
    const g = this.viewer.gizmo;
    g.attach(this.viewer.pivotObject);
    g.addEventListener("objectChange", () => {
      const o = this.viewer.pivotObject;
      const c = this.session?.anchorCentroid;
      if (!c) return;
      // Uniform scale: take the axis the user pulled (largest change from the current scale).
      const prev = this.moveState.scale;
      const axes = [o.scale.x, o.scale.y, o.scale.z];
      let s = axes.reduce((a, b) => (Math.abs(b - prev) > Math.abs(a - prev) ? b : a), prev);
      s = Math.max(0.05, s);
      o.scale.setScalar(s);
      const q = o.quaternion;
      this.submitMove({ translation: [o.position.x - c.x, o.position.y - c.y, o.position.z - c.z], rotation: [q.w, q.x, q.y, q.z], scale: s }, performance.now());
    });
    g.addEventListener("dragging-changed", (e: any) => {
      if (!e.value) this.dragEnd();
    });
  }

  /** Gizmo at pivot + translation (the centroid of the moved anchors), with the group's R and s. */
  private placeGizmo(): void {
    const s = this.session;
    const o = this.viewer.pivotObject;
    const c = s?.anchorCentroid;
    const show = !!c && s!.role === "edit" && this.tool === "move";
    this.viewer.gizmo.getHelper().visible = show;
    this.viewer.gizmo.enabled = show;
    if (!c) return;
    const m = this.moveState;
    o.position.set(c.x + m.translation[0], c.y + m.translation[1], c.z + m.translation[2]);
    o.quaternion.set(m.rotation[1], m.rotation[2], m.rotation[3], m.rotation[0]);
    o.scale.setScalar(m.scale);
    this.viewer.requestRender();
  }

  // ---------- Watch ----------

  private async watchLoop(s: Session, gen: number): Promise<void> {
    let backoff = 250;
    while (s.watchGen === gen) {
      const ac = new AbortController();
      s.watchAbort = ac;
      try {
        const stream = client.watch(
          { sessionId: s.creds.sessionId, token: s.creds.token, encoding: ENCODING },
          { signal: ac.signal, contextValues: createContextValues().set(kSessionId, s.creds.sessionId) },
        );
        for await (const upd of stream) {
          if (s.watchGen !== gen) return;
          backoff = 250;
          this.onUpdate(s, upd);
        }
        if (s.watchGen === gen) {
          // Ends OK only when the session is closed: nothing to reconnect to.
          this.banner.message("The session was closed.");
          this.banner.status("Session closed");
          hooks.ready = false;
        }
        return;
      } catch (e) {
        if (s.watchGen !== gen) return;
        const code = ConnectError.from(e).code;
        if (code === Code.NotFound || code === Code.PermissionDenied || code === Code.InvalidArgument) {
          this.banner.error("Watch failed", e);
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
    const bytes = toBinary(DeformUpdateSchema, upd).length;
    const r = upd.result!;
    this.metrics.updateBytes.push(bytes);
    this.metrics.updateEncodings.push(encodingName(r.encoding));
    showBytes(bytes, encodingName(r.encoding));
    let applied;
    try {
      applied = s.state.apply(upd);
    } catch (e) {
      this.banner.error("Bad update", e);
      return;
    }
    if (!applied.applied) return;
    const rev = s.state.revision;
    this.viewer.updatePositions(s.state.positions);
    if ($in("heatmap").checked) this.recolor();
    showResult(r, rev);
    hooks.revision = rev;
    this.metrics.updatesRendered++;
    if (upd.isSnapshot) s.resolveSnapshot();
    if (!this.gizmoDragging()) this.placeGizmo();
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

  private gizmoDragging(): boolean {
    return this.viewer.gizmo.dragging;
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
      for (let i = 0; i < n; i++) {
        const role = s.selection.role[i];
        const c = role === 1 ? COLORS.fixed : role === 2 ? COLORS.handle : s.selection.magnify[i] ? COLORS.magnify : COLORS.base;
        rgb[i * 3] = c[0]; rgb[i * 3 + 1] = c[1]; rgb[i * 3 + 2] = c[2];
      }
    }
    this.viewer.setColors(rgb);
  }

  private paint(ix: number[]): void {
    const s = this.session;
    if (!s) return;
    const mode = $sel("paint-mode").value as PaintMode;
    if (ix.length === 0) {
      if (this.tool === "lasso") this.banner.message("The lasso selected no vertex facing the camera.");
      return;
    }
    s.selection.paint(ix, mode);
    if (mode === "magnify" || mode === "erase") this.resendIfMoved();
    this.recolor();
  }

  private meshScale(): number {
    const bb = this.viewer.geometry?.boundingBox;
    return bb ? bb.getSize(new THREE.Vector3()).length() : 1;
  }

  // ---------- controls ----------

  private setTool(t: Tool): void {
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

  private resendIfMoved(): void {
    if (this.moved) this.submitMove(this.moveState, performance.now(), true);
  }

  private updateUndoButtons(): void {
    const edit = this.session?.role === "edit";
    $btn("undo").disabled = !edit || !this.history.canUndo;
    $btn("redo").disabled = !edit || !this.history.canRedo;
  }

  private undoRedo(redo: boolean): void {
    if (this.session?.role !== "edit") return;
    const st = redo ? this.history.redo() : this.history.undo();
    if (!st) return;
    this.submitMove(st, performance.now(), true);
    this.placeGizmo();
    this.updateUndoButtons();
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
      this.recolor();
    });
    const radius = () => ($("brush-radius-val").textContent = `${(Number($in("brush-radius").value) * 100).toFixed(1)}% of size`);
    $in("brush-radius").addEventListener("input", radius);
    radius();
    for (const id of ["method", "ora", "iterations"]) $(id).addEventListener("change", () => this.resendIfMoved());
    $in("rigidity").addEventListener("input", () => this.showRigidity());
    $in("rigidity").addEventListener("change", () => this.resendIfMoved());  // re-solves live
    $sel("method").addEventListener("change", () => this.showRigidity());
    $in("magnify").addEventListener("input", () => ($("magnify-val").textContent = Number($in("magnify").value).toFixed(2)));
    $in("magnify").addEventListener("change", () => {
      if (this.session && this.session.selection.magnifyIndices().length === 0) this.banner.message("Paint a “magnify region” first (Brush or Lasso, mode magnify region).");
      this.resendIfMoved();
    });
    $in("heatmap").addEventListener("change", () => this.recolor());
    $sel("heatmap-mode").addEventListener("change", () => this.recolor());
    $("reset-view").addEventListener("click", () => this.viewer.frame());
    $("undo").addEventListener("click", () => this.undoRedo(false));
    $("redo").addEventListener("click", () => this.undoRedo(true));
    window.addEventListener("keydown", (e) => {
      if ((e.target as HTMLElement)?.tagName === "INPUT" && (e.target as HTMLInputElement).type !== "range") return;
      if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") {
        e.preventDefault();
        this.undoRedo(e.shiftKey);
      } else if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "y") {
        e.preventDefault();
        this.undoRedo(true);
      } else if (!e.ctrlKey && !e.metaKey && !e.altKey) {
        const k = e.key.toLowerCase();
        if (k === "w") this.setGizmoMode("translate");
        else if (k === "e") this.setGizmoMode("rotate");
        else if (k === "r") this.setGizmoMode("scale");
      }
    });
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
      if (this.session?.role !== "edit") return;
      e.preventDefault();
      $("drop").hidden = false;
    });
    stage.addEventListener("dragleave", () => ($("drop").hidden = true));
    stage.addEventListener("drop", (e) => {
      e.preventDefault();
      $("drop").hidden = true;
      const f = e.dataTransfer?.files?.[0];
      if (f && this.session?.role === "edit") void this.upload(f);
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
    try {
      await this.banner.progress(`Uploading ${file.name}…`, async () => {
        const bytes = new Uint8Array(await file.arrayBuffer());
        this.banner.status(`Uploading ${file.name} (${(bytes.length / 1024).toFixed(0)} KiB)…`);
        const r = await client.createSession({ source: { case: "meshBytes", value: bytes }, format, lambda: LAMBDA, weld: format === MeshFormat.STL || format === MeshFormat.OBJ });
            const creds = { sessionId: r.sessionId, token: r.editToken };
        await this.load(creds, "edit", r.info!, r.viewToken, r.editToken);
        history.replaceState(null, "", location.pathname + location.search + formatHash(creds));
        this.banner.status(`Uploaded ${file.name}: ${r.info!.vertices.toLocaleString("en")} vertices${r.weldedVertices ? `, ${r.weldedVertices} welded` : ""}`);
      });
    } catch (e) {
      // The current session stays on screen (load() only switches after the new mesh parsed).
      this.banner.error("Upload failed", e);
    }
  }

  private async download(format: MeshFormat, ext: string, mime: string): Promise<void> {
    const s = this.session;
    if (!s) return;
    try {
      const r = await this.banner.progress("Preparing download…", () =>
        client.getMesh({ sessionId: s.creds.sessionId, token: s.creds.token, format, revision: BigInt(Math.max(0, s.state.revision)) }).catch(() =>
          client.getMesh({ sessionId: s.creds.sessionId, token: s.creds.token, format })));
      const url = URL.createObjectURL(new Blob([r.meshBytes as BlobPart], { type: mime }));
      const a = document.createElement("a");
      a.href = url;
      a.download = `meshdeform-${s.creds.sessionId.slice(0, 8)}-r${s.state.revision}.${ext}`;
      document.body.appendChild(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(url), 10_000);
    } catch (e) {
      this.banner.error("Download failed", e);
    }
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
  handleScreenPoint() {
    const c = app.session ? (app as any).handleCentroid() as THREE.Vector3 | null : null;
    if (!c) return null;
    const s = app.viewer.toScreen(c.x, c.y, c.z);
    return s ? { x: s[0], y: s[1] } : null;
  },
  positions() {
    return Array.from(app.session?.state.positions ?? []);
  },
  metrics() {
    const m = app.metrics;
    return { dragToFrameMs: [...m.dragToFrameMs], updateBytes: [...m.updateBytes], updateEncodings: [...m.updateEncodings], updatesRendered: m.updatesRendered, frameWorkMs: [...app.viewer.frameWorkMs] };
  },
  groups() {
    return (app.session?.groups ?? []).map((g) => ({ role: g.role === HandleRole.FIXED ? "fixed" as const : "handle" as const, vertices: [...g.vertices] }));
  },
  resetMetrics() {
    app.metrics.dragToFrameMs.length = 0;
    app.metrics.updateBytes.length = 0;
    app.metrics.updateEncodings.length = 0;
    app.metrics.updatesRendered = 0;
    app.viewer.frameWorkMs.length = 0;
  },
};
(window as unknown as { __meshdeform: Hooks }).__meshdeform = hooks;
app.start();
