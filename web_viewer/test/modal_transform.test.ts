import { describe, expect, it } from "vitest";
import * as THREE from "three";
import { ModalTransform, type ModalHost } from "../src/app/modal_transform";
import { cloneStates, identityStates, type GroupStates } from "../src/moves";
import type { Entry } from "../src/timeline";
import type { Viewer3D } from "../src/scene";

// A page with two applied groups, seen along -z: screen pixel (x, y) is world (x / 100, y / 100).
function page(over: Partial<ModalHost> = {}) {
  const log = {
    moves: [] as GroupStates[], recorded: [] as (Entry | null)[], reverted: [] as GroupStates[],
    shown: [] as string[], explained: 0, orbit: true,
  };
  let states = identityStates(2);
  const viewer = {
    orbit: {
      get enabled() { return log.orbit; },
      set enabled(v: boolean) { log.orbit = v; },
    },
    toScreen: (x: number, y: number) => [x * 100, y * 100],
    viewDirection: () => new THREE.Vector3(0, 0, -1),
    ray: (x: number, y: number) => new THREE.Ray(new THREE.Vector3(x / 100, y / 100, 10), new THREE.Vector3(0, 0, -1)),
  } as unknown as Viewer3D;
  const host: ModalHost = {
    viewer: () => viewer,
    states: () => states,
    setStates: (st) => { states = st; },
    blocked: () => ({ dirty: false, busy: false }),
    lastPointer: () => ({ x: 10, y: 20 }),
    selectedHandle: () => 1,
    handleIndices: () => [1],
    selectGroup: () => {},
    explainBlocked: () => { log.explained++; },
    anchorCentroid: () => new THREE.Vector3(0, 0, 0),
    newGestureEntry: () => ({ states: [] }) as unknown as Entry,
    setGizmoMode: () => {},
    opened: () => {},
    placeGizmo: () => {},
    submitMove: (st) => { states = cloneStates(st); log.moves.push(cloneStates(st)); },
    afterCommand: (entry) => { log.recorded.push(entry); },
    revertSent: (base) => { log.reverted.push(base); },
    endGesture: () => {},
    show: (text) => { log.shown.push(text); },
    ...over,
  };
  return { modal: new ModalTransform(host), log, states: () => states };
}

describe("G / R / S commands against the page", () => {
  it("G moves the selected group by the pointer's travel on the view plane", () => {
    const { modal, log, states } = page();
    expect(modal.start("g")).toBe(true);
    expect(modal.active).toBe(true);
    expect(log.orbit).toBe(false); // the pointer belongs to the command, not the camera
    modal.pointer(60, -30); // from (10, 20): 50 px right, 50 px up in screen units of 1/100
    const t = states()[1].translation;
    expect(t[0]).toBeCloseTo(0.5);
    expect(t[1]).toBeCloseTo(-0.5);
    expect(t[2]).toBeCloseTo(0);
    expect(states()[0].translation).toEqual([0, 0, 0]); // only the selected group moves
    modal.feed("Enter");
    expect(modal.active).toBe(false);
    expect(log.orbit).toBe(true);
    expect(log.recorded).toHaveLength(1);
    expect(log.recorded[0]!.states[1].translation[0]).toBeCloseTo(0.5);
    expect(log.shown[log.shown.length - 1]).toBe("");
  });

  it("Esc after moves puts the group back and undoes the sent moves on the server", () => {
    const { modal, log, states } = page();
    modal.start("g");
    modal.pointer(40, 20);
    expect(states()[1].translation[0]).toBeCloseTo(0.3);
    modal.feed("Escape");
    expect(modal.active).toBe(false);
    expect(states()[1].translation).toEqual([0, 0, 0]);
    expect(log.reverted).toHaveLength(1);
    expect(log.recorded).toHaveLength(0);
  });

  it("Esc before anything was sent asks the server for nothing", () => {
    const { modal, log } = page({ lastPointer: () => null });
    modal.start("r");
    modal.feed("Escape");
    expect(log.moves).toHaveLength(0);
    expect(log.reverted).toHaveLength(0);
  });

  it("a typed amount moves along the locked axis; a command that ends where it started records nothing", () => {
    const { modal, log, states } = page();
    modal.start("g");
    for (const k of ["x", "2"]) modal.feed(k);
    expect(states()[1].translation).toEqual([2, 0, 0]);
    modal.feed("Backspace");
    modal.feed("0");
    modal.feed("Enter");
    expect(states()[1].translation).toEqual([0, 0, 0]);
    expect(log.recorded).toEqual([null]);
  });

  it("a blocked page opens no command and says why; other keys are not commands", () => {
    const { modal, log } = page({ blocked: () => ({ dirty: false, busy: true }) });
    expect(modal.start("q")).toBe(false);
    expect(modal.start("s")).toBe(true); // the key is taken, the command is not opened
    expect(modal.active).toBe(false);
    expect(log.explained).toBe(1);
  });
});
