// The undo history kept in step with the server's: the page's Timeline (src/timeline.ts says what
// a step is and how to reach it exactly) carried out against the session, one history operation
// at a time with moves held meanwhile: undo and redo, the cancel of a G / R / S command whose
// moves reached the server, Reset to rest, the history an opened session continues, and the
// server's step positions and revisions. Owns the server's history position as last answered,
// the queue of history operations and whether one is running.
import { Code } from "@connectrpc/connect";
import {
  HandleRole, HistoryAction, Method,
  type GroupMove, type MoveHandlesRequest, type MoveHandlesResponse, type SessionInfo,
} from "../gen/meshdeform/v1/deformation_pb";
import { entriesFromEdit } from "../edit_state";
import { errorCode, type Action } from "../errors";
import type { GroupSpec } from "../groups";
import { DEFAULT_ITERATIONS } from "../iterations";
import { applyMove, cloneStates, fitSimilarity, identityStates, planReset, type GroupStates, type Vec3 } from "../moves";
import { rigidityStep } from "../rigidity";
import { derive, type Entry, type Settings } from "../timeline";
import { $, $btn, $in } from "../ui/dom";
import { client } from "./config";
import type { PageState } from "./page";
import type { SettingsRequest } from "./settings_panel";
import { centroidOfRows, type MoveTarget, type Session } from "./session";

/** What the history needs from the page. */
export interface HistoryHost extends PageState {
  /** The painted groups differ from the applied ones. */
  dirty(): boolean;
  closeModal(): void;
  fail(prefix: string, e: unknown, action: Action): void;
  handleIndices(): number[];
  appliedSpecs(): GroupSpec[];
  applyHandles(): Promise<boolean>;
  /** SetHandles alone (a new epoch), or as a step of the history. */
  setHandlesRaw(specs: GroupSpec[]): Promise<void>;
  setHandles(specs: GroupSpec[], capture: boolean): Promise<void>;
  /** Paints `specs` (null: the applied groups) as a state's painted groups. */
  showDraft(specs: GroupSpec[] | null): void;
  groupMoves(states: GroupStates): GroupMove[];
  settingsRequest(): SettingsRequest;
  currentSettings(): Settings;
  applySettings(st: Settings): void;
  recolor(): void;
  renderGroups(): void;
  updateReady(): void;
  placeGizmo(): void;
}

export class HistorySync {
  /** The server's undo-history position, as its last answer said. */
  private serverPos = 0;
  private chain: Promise<void> = Promise.resolve();
  busy = false;

  constructor(private readonly host: HistoryHost) {}

  updateButtons(): void {
    const s = this.host.session();
    const edit = s?.role === "edit" && !s.gone;
    $btn("undo").disabled = !edit || !this.host.timeline.canUndo;
    $btn("redo").disabled = !edit || !this.host.timeline.canRedo;
    this.host.hooks.historyBusy = this.busy;
  }

  /** An opened session's undo history and the groups' current moves, as the server keeps them
   * (the groups and their anchors are adopted already; `n`: the mesh's vertex count). */
  restore(s: Session, info: SessionInfo, n: number): void {
    const h = this.host;
    const timeline = h.timeline;
    timeline.clear();
    const epoch = timeline.addEpoch({ groups: h.appliedSpecs(), anchors: s.anchors.map((a) => a.positions) });
    // A step without settings: the first of a session without moves (the defaults), or one stored
    // before steps kept theirs (the session's).
    const defaults: Settings = {
      method: Method.SCALE_AWARE, ora: false, rigidityStep: rigidityStep(info.rigidity), iterations: DEFAULT_ITERATIONS, magnifyScale: 1, magnify: [],
    };
    const restored = entriesFromEdit(info.edit, s.anchors.map((a) => (a.centroid ? (a.centroid.toArray() as Vec3) : null)),
      (i, step) => (i === 0 && step && step.moves.length === 0 && step.targets === undefined ? defaults : h.currentSettings()), n);
    timeline.restore(restored.entries.map((e) => ({ ...e, epoch })), restored.index);
    this.serverPos = restored.index;
    h.setStates(cloneStates(timeline.current?.states ?? identityStates(s.groups.length)));
    this.updateButtons();
  }

  /** A SetHandles: the server's history starts again. */
  restarted(): void {
    this.serverPos = 0;
  }

  /** The server's step revisions for the live epoch's history entries (before the server's
   * history is replaced: a SetHandles, or a restore that drops its redo branch). */
  async captureRevisions(): Promise<void> {
    const s = this.host.session();
    if (!s) return;
    const r = await client.getSessionInfo({ sessionId: s.creds.sessionId, token: s.creds.token });
    const edit = r.info?.edit;
    if (!edit) return;
    this.host.timeline.takeRevisions(edit.steps.map((st) => (st.revision === undefined ? null : Number(st.revision))));
    this.serverPos = edit.position;
  }

  /** A move's answer: its server step, for the history (`t`: the coalesced move it answers). */
  answered(r: MoveHandlesResponse, t: MoveTarget | null): void {
    const rev = Number(r.result?.revision ?? -1);
    if (r.result?.historyPosition !== undefined) {
      this.serverPos = r.result.historyPosition;
      if (t?.entry) {
        t.entry.serverPos = this.serverPos;
        t.entry.epoch = this.host.timeline.live;
        t.entry.revision = rev >= 0 ? rev : null;
      }
    }
  }

  /** A MoveHandles outside the coalescer (history steps, restores), with the controls' settings. */
  private move(parts: Omit<Partial<MoveHandlesRequest>, "$typeName" | "$unknown">): Promise<MoveHandlesResponse> {
    const s = this.host.session()!;
    return client.moveHandles({ sessionId: s.creds.sessionId, token: s.creds.token, ...this.host.settingsRequest(), ...parts }, { timeoutMs: 60_000 });
  }

  /** Runs `op` after every queued move and history step, with moves held meanwhile. */
  private run(op: () => Promise<void>, prefix: string, action: Action): Promise<void> {
    const h = this.host;
    const run = async () => {
      const s = h.session();
      if (!s || s.gone) return;
      await h.coalescer.idle();
      this.busy = true;
      this.updateButtons();
      try {
        await op();
      } catch (e) {
        h.fail(prefix, e, action);
      } finally {
        // The server's state is no longer the last move sent: the same target must be sent again.
        h.coalescer.reset();
        this.busy = false;
        this.updateButtons();
        h.recolor();
        h.renderGroups();
        h.updateReady();
        h.placeGizmo();
      }
    };
    this.chain = this.chain.then(run, run);
    return this.chain;
  }

  undoRedo(redo: boolean): void {
    const s = this.host.session();
    if (s?.role !== "edit" || s.gone) return;
    this.host.closeModal();
    void this.run(() => this.step(redo), redo ? "Redo failed" : "Undo failed", "move");
  }

  /** One step of the page's history (timeline.ts says how it stays exact). */
  private async step(redo: boolean): Promise<void> {
    const h = this.host;
    const timeline = h.timeline;
    const s = h.session()!;
    const to = timeline.target(redo);
    const from = timeline.current;
    if (!to || !from) return;
    let plan = timeline.plan(to, s.state.revision, h.appliedSpecs());
    if (plan.setGroups || plan.shape.kind === "restore" || plan.shape.kind === "solve") {
      await this.captureRevisions();
      plan = timeline.plan(to, s.state.revision, h.appliedSpecs());
    }
    const fromPos = this.serverPos;
    if (plan.setGroups) await h.setHandlesRaw(plan.setGroups);
    h.applySettings(to.settings);
    const live = timeline.live;
    const states = to.epoch === live ? cloneStates(to.states) : plan.setGroups && plan.shape.kind === "none" ? identityStates(s.groups.length) : this.rebase(to);
    const shape = plan.shape;
    if (shape.kind === "history") {
      const r = await this.move({ history: shape.action === "undo" ? HistoryAction.UNDO : HistoryAction.REDO });
      this.answered(r, null);
      to.revision = Number(r.result?.revision ?? -1);
      if (this.serverPos !== to.serverPos) {
        // The server's history was not where the page thought (it drops its oldest steps past
        // 100): put the state back by its positions instead.
        await this.restoreOrSolve(to, states, fromPos);
      }
    } else if (shape.kind === "restore" || shape.kind === "solve") {
      await this.restoreOrSolve(to, states, plan.setGroups ? 0 : fromPos);
    } else if (plan.setGroups) {
      to.epoch = live;
      to.serverPos = 0;
      to.revision = s.state.revision;
    }
    h.setStates(states);
    to.states = cloneStates(states);
    // The painted groups of that state.
    h.showDraft(to.draft);
    timeline.step(redo);
    if (to.revision !== null) await this.waitForRevision(s, to.revision);
  }

  /** Commits `to`'s kept positions again (restore_revision) with `states` as its moves, or, when
   * the server no longer keeps them, solves for those moves. */
  private async restoreOrSolve(to: Entry, states: GroupStates, fromPos: number): Promise<void> {
    let r: MoveHandlesResponse | null = null;
    if (to.revision !== null) {
      try {
        r = await this.move({ moves: this.host.groupMoves(states), restoreRevision: BigInt(to.revision) });
      } catch (e) {
        if (errorCode(e) !== Code.FailedPrecondition) throw e;
        r = null; // no longer kept: solve
      }
    }
    if (!r) {
      this.host.banner.status("That step's shape is no longer kept by the server: solved again (close to it, not exact)");
      r = await this.move({ moves: this.host.groupMoves(states) });
    }
    this.answered(r, null);
    this.host.timeline.recorded(to, this.serverPos, fromPos);
    to.revision = Number(r.result?.revision ?? -1);
  }

  /** `e`'s moves re-expressed about the live anchors: each group's targets (its moves applied to
   * its own epoch's anchors) fitted by a similarity of the live anchors. */
  private rebase(e: Entry): GroupStates {
    const s = this.host.session()!;
    const ep = this.host.timeline.epoch(e.epoch);
    return s.groups.map((g, i) => {
      if (g.role !== HandleRole.HANDLE || !ep || !ep.anchors[i] || !e.states[i]) return identityStates(1)[0];
      const from = ep.anchors[i];
      const c = centroidOfRows(from)!;
      const targets: number[] = [];
      for (let k = 0; k < from.length; k += 3) targets.push(...applyMove(e.states[i], [c.x, c.y, c.z], [from[k], from[k + 1], from[k + 2]]));
      return fitSimilarity(s.anchors[i].positions, targets);
    });
  }

  /** A cancelled G / R / S command whose moves reached the server: its step undone there. */
  revertModal(base: GroupStates): void {
    void this.run(async () => {
      const timeline = this.host.timeline;
      const cur = timeline.current;
      if (this.serverPos === (cur?.serverPos ?? -1) + 1 && cur && cur.epoch === timeline.live) {
        const r = await this.move({ history: HistoryAction.UNDO });
        this.answered(r, null);
      } else if (cur?.revision !== null && cur) {
        const r = await this.move({ moves: this.host.groupMoves(base), restoreRevision: BigInt(cur.revision) });
        this.answered(r, null);
        timeline.recorded(cur, this.serverPos, this.serverPos - 1);
        cur.revision = Number(r.result?.revision ?? -1);
      }
      this.host.setStates(cloneStates(base));
    }, "Cancel failed", "move");
  }

  /** Every handle back to its rest position, the mesh back to the rest pose exactly: the
   * server commits revision 0's positions again (restore_revision), no solve. */
  async resetToRest(): Promise<void> {
    const h = this.host;
    const s = h.session();
    if (!s || s.role !== "edit" || s.gone || h.handleIndices().length === 0) return;
    if (h.dirty() && !(await h.applyHandles())) return;
    const plan = planReset(s.restKnown, s.anchorsAtRest);
    if (plan === "unavailable") {
      h.banner.message("Reset is not possible: the server no longer keeps this session's rest mesh.");
      return;
    }
    h.closeModal();
    await this.run(async () => {
      $in("magnify").value = "1";
      $("magnify-val").textContent = "1.00";
      if (plan === "identity") {
        const id = identityStates(s.groups.length);
        const entry = derive(h.timeline.current!, { states: id, settings: h.currentSettings(), serverPos: -1, revision: null, draft: null });
        const r = await this.move({ moves: h.groupMoves(id), restoreRevision: 0n });
        h.setStates(id);
        this.answered(r, null);
        entry.serverPos = this.serverPos;
        entry.revision = Number(r.result?.revision ?? -1);
        h.timeline.push(entry);
      } else {
        // The anchors are a deformed shape: the rest pose first, then the same groups set again
        // there (anchors = rest): one step of the history. The steps' revisions are taken
        // before the restore makes the rest pose the server's current one.
        await this.captureRevisions();
        const r = await this.move({ moves: [], restoreRevision: 0n });
        this.answered(r, null);
        await this.waitForRevision(s, Number(r.result?.revision ?? 0));
        await h.setHandles(h.appliedSpecs(), false);
      }
      h.banner.status("Reset to rest");
    }, "Reset failed", "reset");
  }

  /** Resolves once the frame of `revision` (or a later one) is on screen (bounded: 30 s). */
  private waitForRevision(s: Session, revision: number): Promise<void> {
    return new Promise((resolve) => {
      const t0 = performance.now();
      const tick = () => (s.state.revision >= revision || performance.now() - t0 > 30_000 || s.gone ? resolve() : setTimeout(tick, 20));
      tick();
    });
  }
}
