// The page's undo history (issue 44): every step is a whole page state — the applied handle
// groups (an "epoch": one SetHandles, with the anchors it set), every group's move about those
// anchors, the solver settings, the painted groups when they differ from the applied ones, and the
// revision whose positions show it. Drags, numeric and modal transforms, settings changes, reset,
// painting, deleting and applying groups are all steps.
//
// Undo and redo go from one state to the other exactly: the server keeps the positions of the
// steps it leaves (EditStep.revision), so within one epoch the server's own UNDO / REDO commit
// them again, and across a handle change the page sets the other groups again (on the current
// shape) and asks for the revision's positions back (MoveHandlesRequest.restore_revision), with
// the moves re-expressed about the new anchors. Only a state whose positions the server no longer
// keeps is solved again. Pure: app/history_sync.ts carries the plans out.
import type { GroupSpec } from "./groups";
import { cloneStates, type GroupStates } from "./moves";

/** The solver settings a step was solved with, as the controls show them. */
export interface Settings {
  method: number;
  ora: boolean;
  rigidityStep: number;
  iterations: number;
  magnifyScale: number;
  /** The magnify region (vertex indices, ascending; shared, never mutated). */
  magnify: readonly number[];
}

export function sameSettings(a: Settings, b: Settings): boolean {
  return a.method === b.method && a.ora === b.ora && a.rigidityStep === b.rigidityStep && a.iterations === b.iterations &&
    a.magnifyScale === b.magnifyScale && sameList(a.magnify, b.magnify);
}

function sameList(a: readonly number[], b: readonly number[]): boolean {
  if (a === b) return true;
  if (a.length !== b.length) return false;
  for (let i = 0; i < a.length; i++) if (a[i] !== b[i]) return false;
  return true;
}

export function sameSpecs(a: readonly GroupSpec[], b: readonly GroupSpec[]): boolean {
  return a.length === b.length && a.every((g, i) => g.role === b[i].role && sameList(g.vertices, b[i].vertices));
}

/** One SetHandles: the groups and their anchors (3 per vertex, each group's vertices in order). */
export interface Epoch {
  groups: GroupSpec[];
  anchors: Float32Array[];
}

export interface Entry {
  epoch: number;
  /** The step of the server's history (of a live epoch) this state is; -1 when not known. */
  serverPos: number;
  states: GroupStates;
  settings: Settings;
  /** The painted groups when they differ from the applied ones (not applied yet), else null. */
  draft: GroupSpec[] | null;
  /** The revision whose positions show this state, as the server attributes it; null unknown. */
  revision: number | null;
}

export type ShapePlan =
  | { kind: "none" }
  | { kind: "history"; action: "undo" | "redo" }
  | { kind: "restore"; revision: number }
  | { kind: "solve" };

/** How to get from the current state to another. */
export interface Plan {
  /** Set these groups first (the target's differ from the applied ones); null: keep them. */
  setGroups: GroupSpec[] | null;
  shape: ShapePlan;
  /** The target's moves are about another epoch's anchors: re-express them on the live ones. */
  rebase: boolean;
}

export const MAX_STEPS = 100;

export class Timeline {
  private entries: Entry[] = [];
  private index = -1;
  private readonly epochs = new Map<number, Epoch>();
  private nextEpoch = 1;
  /** The epoch whose history the server holds now (its last SetHandles). */
  live = -1;

  constructor(private readonly limit = MAX_STEPS) {}

  get current(): Entry | null {
    return this.index >= 0 ? this.entries[this.index] : null;
  }
  get canUndo(): boolean {
    return this.index > 0;
  }
  get canRedo(): boolean {
    return this.index >= 0 && this.index < this.entries.length - 1;
  }
  get size(): number {
    return this.entries.length;
  }
  get position(): number {
    return this.index;
  }
  entry(i: number): Entry | null {
    return this.entries[i] ?? null;
  }
  epoch(id: number): Epoch | null {
    return this.epochs.get(id) ?? null;
  }

  /** A new SetHandles: the server's history restarts; returns the epoch's id (now live). */
  addEpoch(e: Epoch): number {
    const id = this.nextEpoch++;
    this.epochs.set(id, e);
    this.live = id;
    return id;
  }

  /** Starts afresh (a new session, or a reload that takes over the server's history). */
  clear(): void {
    this.entries = [];
    this.index = -1;
    this.epochs.clear();
    this.live = -1;
  }

  /** Forgets every state, keeping the epochs in use (the live one). */
  clearEntries(): void {
    this.entries = [];
    this.index = -1;
    this.dropUnusedEpochs();
  }

  /** Adds `e` after the current state (dropping the redo branch) unless it equals it. */
  push(e: Entry): void {
    const cur = this.current;
    if (cur && sameEntry(cur, e)) return;
    this.entries.splice(this.index + 1);
    this.entries.push(e);
    this.index++;
    while (this.entries.length > this.limit) {
      this.entries.shift();
      this.index--;
    }
    this.dropUnusedEpochs();
  }

  /** Replaces the whole history (a reload: the server's), current at `index`. */
  restore(entries: Entry[], index: number): void {
    this.entries = entries.slice(-this.limit);
    const dropped = entries.length - this.entries.length;
    this.index = Math.min(Math.max(0, index - dropped), this.entries.length - 1);
  }

  /** The entry an undo (or redo) goes to, or null. */
  target(redo: boolean): Entry | null {
    return redo ? (this.canRedo ? this.entries[this.index + 1] : null) : this.canUndo ? this.entries[this.index - 1] : null;
  }

  /** Moves the current position one step (after the plan was carried out). */
  step(redo: boolean): void {
    this.index += redo ? 1 : -1;
  }

  /**
   * How to reach `to` from the current state. `shown`: the revision on screen; `liveGroups`: the
   * groups applied now.
   */
  plan(to: Entry, shown: number, liveGroups: GroupSpec[]): Plan {
    const from = this.current;
    const toEpoch = this.epochs.get(to.epoch);
    const setGroups = toEpoch && !sameSpecs(toEpoch.groups, liveGroups) ? toEpoch.groups : null;
    const live = setGroups ? -2 : this.live; // a SetHandles makes a new live epoch
    let shape: ShapePlan;
    if (to.revision !== null && to.revision === shown) {
      shape = { kind: "none" };
    } else if (from && !setGroups && to.epoch === live && from.epoch === live && to.serverPos >= 0 && from.serverPos >= 0 &&
      Math.abs(to.serverPos - from.serverPos) === 1) {
      shape = { kind: "history", action: to.serverPos < from.serverPos ? "undo" : "redo" };
    } else if (to.revision !== null) {
      shape = { kind: "restore", revision: to.revision };
    } else {
      shape = { kind: "solve" };
    }
    return { setGroups, shape, rebase: to.epoch !== live };
  }

  /** The server recorded a step for `e` at `pos` of the live epoch (a restore, a solve): the
   * states past the previous server position lost their server steps (its redo branch). */
  recorded(e: Entry, pos: number, fromPos: number): void {
    for (const x of this.entries) {
      if (x !== e && x.epoch === this.live && x.serverPos > fromPos) this.detach(x);
    }
    e.epoch = this.live;
    e.serverPos = pos;
  }

  /** Takes the server's step revisions for the live epoch's states (GetSessionInfo). */
  takeRevisions(stepRevisions: (number | null)[]): void {
    for (const x of this.entries) {
      if (x.epoch === this.live && x.serverPos >= 0 && x.serverPos < stepRevisions.length) x.revision = stepRevisions[x.serverPos];
    }
  }

  /** Gives `x` an epoch of its own with the same groups and anchors (no server history). */
  private detach(x: Entry): void {
    const e = this.epochs.get(x.epoch);
    if (!e) return;
    const id = this.nextEpoch++;
    this.epochs.set(id, e);
    for (const y of this.entries) if (y.epoch === x.epoch && y.serverPos === x.serverPos && y !== x) { y.epoch = id; y.serverPos = -1; }
    x.epoch = id;
    x.serverPos = -1;
  }

  private dropUnusedEpochs(): void {
    const used = new Set(this.entries.map((e) => e.epoch));
    used.add(this.live);
    for (const id of [...this.epochs.keys()]) if (!used.has(id)) this.epochs.delete(id);
  }
}

function sameEntry(a: Entry, b: Entry): boolean {
  return a.epoch === b.epoch && sameSettings(a.settings, b.settings) &&
    JSON.stringify(a.states) === JSON.stringify(b.states) &&
    (a.draft === b.draft || (!!a.draft && !!b.draft && sameSpecs(a.draft, b.draft)));
}

/** A copy of `e` with new parts (states copied). */
export function derive(e: Entry, parts: Partial<Entry>): Entry {
  return { ...e, states: cloneStates(e.states), ...parts };
}
