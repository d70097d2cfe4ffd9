// The G / R / S modal transforms: a key opens a command on the selected handle group, the pointer
// (or typed digits) sets its amount and every change is sent as a move, Enter or a click applies
// it as one undo step, Esc or a right-click puts the group back. No DOM here: the page is the host.
import * as THREE from "three";
import { describeCommand, effectiveAxis, feedKey, startCommand, typedValue, type KeyCommand } from "../keycmd";
import { modalState, type ModalPointer } from "../modal";
import { cloneStates, statesKey, type GroupStates, type Vec3 } from "../moves";
import { newGesture } from "../edit_state";
import type { Entry } from "../timeline";
import type { Viewer3D } from "../scene";

/** An open G / R / S command. */
interface Modal {
  cmd: KeyCommand;
  group: number;
  base: GroupStates;
  gesture: bigint;
  entry: Entry;
  start: { x: number; y: number } | null;
  now: { x: number; y: number } | null;
  sent: boolean;
  label: string;
}

/** What a command needs from the page. */
export interface ModalHost {
  viewer(): Viewer3D;
  /** Every applied group's move, as the page holds it (read and replaced). */
  states(): GroupStates;
  setStates(states: GroupStates): void;
  /** No command may open: painted changes wait, a history step or a pick is running. */
  blocked(): { dirty: boolean; busy: boolean };
  /** Where the pointer last was (a command started from the keyboard measures from there). */
  lastPointer(): { x: number; y: number } | null;
  selectedHandle(): number;
  handleIndices(): number[];
  selectGroup(i: number): void;
  /** Tells the user why nothing moves (painted changes to apply, or no handle yet). */
  explainBlocked(): void;
  /** The applied group's anchor centroid (its rotation and scale pivot). */
  anchorCentroid(group: number): THREE.Vector3 | null;
  newGestureEntry(): Entry | null;
  setGizmoMode(mode: "translate" | "rotate" | "scale"): void;
  /** A command opened (the first-use hint goes). */
  opened(): void;
  placeGizmo(): void;
  submitMove(states: GroupStates, t0: number, o: { gesture: bigint; entry: Entry }): void;
  /** A command ended: its entry (null: nothing to record) joins the undo history. */
  afterCommand(entry: Entry | null): void;
  /** The command's moves reached the server: undo them there, back to `base`. */
  revertSent(base: GroupStates): void;
  /** The gesture ended (the full mesh again if its coarse level was drawn). */
  endGesture(): void;
  /** The command line as shown ("" when none is open). */
  show(text: string): void;
}

export class ModalTransform {
  private modal: Modal | null = null;

  constructor(private readonly host: ModalHost) {}

  get active(): boolean {
    return this.modal !== null;
  }

  /** Opens the command a key starts (G, R or S). @return whether the key was one. */
  start(key: string): boolean {
    const cmd = startCommand(key);
    if (!cmd) return false;
    const h = this.host;
    let i = h.selectedHandle();
    const { dirty, busy } = h.blocked();
    if (i < 0 && !dirty && h.handleIndices().length > 0) {
      i = h.handleIndices()[0];
      h.selectGroup(i);
    }
    if (i < 0 || busy) {
      h.explainBlocked();
      return true;
    }
    const p = h.lastPointer();
    this.modal = {
      cmd, group: i, base: cloneStates(h.states()), gesture: newGesture(), entry: h.newGestureEntry()!, start: p ? { ...p } : null,
      now: p ? { ...p } : null, sent: false, label: "",
    };
    h.viewer().orbit.enabled = false;
    h.setGizmoMode(cmd.kind);
    h.opened();
    this.show();
    return true;
  }

  pointer(x: number, y: number): void {
    const m = this.modal;
    if (!m) return;
    if (!m.start) m.start = { x, y };
    m.now = { x, y };
    this.update();
  }

  /** A key while the command is open: digits, axes, Enter, Esc, or another command. */
  feed(key: string): void {
    const m = this.modal;
    if (!m) return;
    const step = feedKey(m.cmd, key);
    if (step.state === "cancel") {
      this.cancel();
      return;
    }
    if (step.state === "apply") {
      m.cmd = step.cmd;
      this.confirm();
      return;
    }
    const restarted = key.length === 1 && /[grs]/i.test(key);
    m.cmd = step.cmd;
    if (restarted) {
      // A new command: from the state the first one started at, the pointer's travel anew.
      m.start = m.now ? { ...m.now } : m.start;
      m.label = "";
      this.host.setGizmoMode(m.cmd.kind);
    }
    this.update();
  }

  confirm(): void {
    const m = this.modal;
    if (!m) return;
    const h = this.host;
    this.update();
    this.close();
    if (m.sent && statesKey(h.states()) !== statesKey(m.base)) {
      m.entry.states = cloneStates(h.states());
      h.afterCommand(m.entry);
    } else {
      // Nothing changed after all: the moves sent were the state it started at.
      if (m.sent) h.setStates(cloneStates(m.base));
      h.afterCommand(null);
    }
    h.placeGizmo();
  }

  /** Esc or a right-click: the group goes back exactly (the server's undo of the command's step). */
  cancel(): void {
    const m = this.modal;
    if (!m) return;
    this.close();
    this.host.setStates(cloneStates(m.base));
    this.host.placeGizmo();
    if (m.sent) this.host.revertSent(m.base);
  }

  close(): void {
    if (!this.modal) return;
    this.modal = null;
    this.host.endGesture();
    this.host.viewer().orbit.enabled = true;
    this.host.show("");
  }

  /** Sends the group's state for the command as it stands (pointer or typed amount). */
  private update(): void {
    const m = this.modal;
    if (!m) return;
    const h = this.host;
    const value = typedValue(m.cmd);
    if (value === null && (!m.start || !m.now)) {
      this.show();
      return;
    }
    const a = h.anchorCentroid(m.group);
    if (!a) return;
    const viewer = h.viewer();
    const t = m.base[m.group].translation;
    const centre = new THREE.Vector3(a.x + t[0], a.y + t[1], a.z + t[2]);
    const cs = viewer.toScreen(centre.x, centre.y, centre.z) ?? [0, 0];
    const start = m.start ?? { x: cs[0], y: cs[1] };
    const now = m.now ?? start;
    const plane = new THREE.Plane().setFromNormalAndCoplanarPoint(viewer.viewDirection(), centre);
    const h0 = viewer.ray(start.x, start.y).intersectPlane(plane, new THREE.Vector3());
    const h1 = viewer.ray(now.x, now.y).intersectPlane(plane, new THREE.Vector3());
    const planeDelta: Vec3 = h0 && h1 ? [h1.x - h0.x, h1.y - h0.y, h1.z - h0.z] : [0, 0, 0];
    const pointer: ModalPointer = {
      centre: [cs[0], cs[1]], start: [start.x, start.y], now: [now.x, now.y], planeDelta,
      towardViewer: viewer.viewDirection().negate().toArray() as Vec3,
    };
    const amount = modalState(m.base[m.group], m.cmd.kind, effectiveAxis(m.cmd), value, pointer);
    m.label = amount.label;
    const st = cloneStates(m.base);
    st[m.group] = amount.state;
    h.submitMove(st, performance.now(), { gesture: m.gesture, entry: m.entry });
    m.sent = true;
    h.placeGizmo();
    this.show();
  }

  private show(): void {
    this.host.show(this.modal ? describeCommand(this.modal.cmd, this.modal.label) : "");
  }
}
