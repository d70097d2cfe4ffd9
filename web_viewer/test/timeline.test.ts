import { describe, expect, it } from "vitest";
import { derive, Timeline, type Entry, type Settings } from "../src/timeline";
import { identityStates, IDENTITY } from "../src/moves";
import type { GroupSpec } from "../src/groups";

const settings: Settings = { method: 1, ora: false, rigidityStep: 6, iterations: 2, magnifyScale: 1, magnify: [] };
const groupsA: GroupSpec[] = [{ role: "fixed", vertices: [0, 1] }, { role: "handle", vertices: [5, 6] }];
const groupsB: GroupSpec[] = [{ role: "fixed", vertices: [0, 1] }];
const moved = (x: number) => [IDENTITY, { ...IDENTITY, translation: [x, 0, 0] as [number, number, number] }];

function entry(epoch: number, serverPos: number, x: number, revision: number | null): Entry {
  return { epoch, serverPos, states: moved(x), settings, draft: null, revision };
}

describe("Timeline", () => {
  it("plans the server's undo and redo between neighbouring steps of the live epoch", () => {
    const t = new Timeline();
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    t.push(entry(a, 0, 0, 0));
    t.push(entry(a, 1, 1, 3));
    t.push(entry(a, 2, 2, 7));
    expect(t.plan(t.target(false)!, 7, groupsA)).toEqual({ setGroups: null, shape: { kind: "history", action: "undo" }, rebase: false });
    t.step(false);
    expect(t.plan(t.target(true)!, 8, groupsA)).toEqual({ setGroups: null, shape: { kind: "history", action: "redo" }, rebase: false });
  });

  it("undoing a group change sets the groups again; the shape is already there", () => {
    const t = new Timeline();
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    t.push(entry(a, 0, 0, 0));
    t.push(entry(a, 1, 1, 3));
    const b = t.addEpoch({ groups: groupsB, anchors: [] }); // a group deleted
    t.push({ epoch: b, serverPos: 0, states: identityStates(1), settings, draft: null, revision: 3 });
    const back = t.plan(t.target(false)!, 3, groupsB);
    expect(back.setGroups).toEqual(groupsA);
    expect(back.shape).toEqual({ kind: "none" });
  });

  it("a state of an earlier epoch is restored by its revision, its moves re-expressed", () => {
    const t = new Timeline();
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    t.push(entry(a, 0, 0, 0));
    t.push(entry(a, 1, 1, 3));
    const b = t.addEpoch({ groups: groupsB, anchors: [] });
    t.push({ epoch: b, serverPos: 0, states: identityStates(1), settings, draft: null, revision: 3 });
    t.step(false);
    // The groups were set again (a new live epoch with groups A): entry 0 is from epoch a.
    t.addEpoch({ groups: groupsA, anchors: [] });
    expect(t.plan(t.target(false)!, 3, groupsA)).toEqual({ setGroups: null, shape: { kind: "restore", revision: 0 }, rebase: true });
    // Without a kept revision: solved again.
    t.entry(0)!.revision = null;
    expect(t.plan(t.target(false)!, 3, groupsA).shape).toEqual({ kind: "solve" });
  });

  it("a recorded restore detaches the states whose server steps it dropped", () => {
    const t = new Timeline();
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    t.push(entry(a, 0, 0, 0));
    t.push(entry(a, 1, 1, 3));
    t.push(entry(a, 2, 2, 7));
    t.step(false);
    t.step(false); // at entry 0, server position 0; entries 1, 2 are the server's redo branch
    const e0 = t.entry(0)!;
    t.recorded(e0, 1, 0); // e.g. a restore recorded as step 1
    expect(e0.serverPos).toBe(1);
    expect(t.entry(1)!.serverPos).toBe(-1);
    expect(t.entry(1)!.epoch).not.toBe(a);
    expect(t.entry(2)!.serverPos).toBe(-1);
    // Redo to entry 1 is now a restore by revision.
    expect(t.plan(t.target(true)!, 9, groupsA).shape).toEqual({ kind: "restore", revision: 3 });
  });

  it("takes the server's step revisions for the live epoch", () => {
    const t = new Timeline();
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    t.push(entry(a, 0, 0, null));
    t.push(entry(a, 1, 1, null));
    t.takeRevisions([4, null]);
    expect(t.entry(0)!.revision).toBe(4);
    expect(t.entry(1)!.revision).toBeNull();
  });

  it("ignores a push equal to the current state and drops the redo branch otherwise", () => {
    const t = new Timeline();
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    t.push(entry(a, 0, 0, 0));
    t.push(entry(a, 1, 1, 3));
    t.push(derive(t.current!, { revision: 99 }));
    expect(t.size).toBe(2);
    t.step(false);
    t.push(entry(a, 1, 5, 9));
    expect(t.size).toBe(2);
    expect(t.canRedo).toBe(false);
    // A draft-only change is a step too.
    t.push(derive(t.current!, { draft: groupsB }));
    expect(t.size).toBe(3);
  });

  it("keeps at most its limit of steps", () => {
    const t = new Timeline(5);
    const a = t.addEpoch({ groups: groupsA, anchors: [] });
    for (let i = 0; i < 9; i++) t.push(entry(a, i, i, i));
    expect(t.size).toBe(5);
    expect(t.current!.states[1].translation[0]).toBe(8);
  });
});
