import { describe, expect, it } from "vitest";
import { GroupSet, groupColor, HANDLE_COLORS } from "../src/groups";

describe("GroupSet", () => {
  it("two separately painted patches are two groups", () => {
    const g = new GroupSet(10);
    g.beginStroke("handle", false);
    g.paint([0, 1]);
    g.paint([2]); // same stroke: same group
    g.endStroke();
    g.beginStroke("handle", false);
    g.paint([7, 8]);
    g.endStroke();
    expect(g.specs()).toEqual([
      { role: "handle", vertices: [0, 1, 2] },
      { role: "handle", vertices: [7, 8] },
    ]);
    expect(g.selected).toBe(1); // the last painted group is selected
  });

  it("extends the selected group only when it has the painted role", () => {
    const g = new GroupSet(10, [
      { role: "fixed", vertices: [0, 1] },
      { role: "handle", vertices: [5] },
    ]);
    g.select(1);
    g.beginStroke("handle", true);
    g.paint([6]);
    g.endStroke();
    expect(g.size).toBe(2);
    expect(g.vertices(1)).toEqual([5, 6]);
    g.select(0);
    g.beginStroke("handle", true); // selected is fixed: a new handle group
    g.paint([9]);
    g.endStroke();
    expect(g.size).toBe(3);
    expect(g.role(2)).toBe("handle");
    expect(g.selected).toBe(2);
  });

  it("keeps every vertex in one group and drops emptied groups", () => {
    const g = new GroupSet(6, [
      { role: "fixed", vertices: [0] },
      { role: "handle", vertices: [1, 2] },
      { role: "handle", vertices: [3] },
    ]);
    g.select(2);
    g.beginStroke("fixed", false);
    g.paint([1, 2]); // group 1 loses both vertices
    g.endStroke();
    expect(g.specs()).toEqual([
      { role: "fixed", vertices: [0] },
      { role: "handle", vertices: [3] },
      { role: "fixed", vertices: [1, 2] },
    ]);
    expect(g.groupOf(1)).toBe(2);
    expect(g.selected).toBe(2); // the new group (renumbered after the drop)
    g.erase([3]);
    expect(g.size).toBe(2);
    expect(g.groupOf(3)).toBe(-1);
  });

  it("deletes a group and renumbers the selection", () => {
    const g = new GroupSet(5, [
      { role: "fixed", vertices: [0] },
      { role: "handle", vertices: [1] },
      { role: "handle", vertices: [2, 3] },
    ]);
    g.select(2);
    g.delete(1);
    expect(g.size).toBe(2);
    expect(g.selected).toBe(1);
    expect(g.vertices(1)).toEqual([2, 3]);
    g.delete(1);
    expect(g.selected).toBe(-1);
  });

  it("compares with the applied groups and validates", () => {
    const applied = [{ role: "fixed" as const, vertices: [0] }, { role: "handle" as const, vertices: [2, 3] }];
    const g = new GroupSet(5, applied);
    expect(g.equals(applied)).toBe(true);
    expect(g.validate()).toBeNull();
    g.beginStroke("handle", false);
    g.paint([4]);
    expect(g.equals(applied)).toBe(false);
    expect(new GroupSet(3).validate()).toMatch(/Nothing painted/);
    expect(new GroupSet(3, [{ role: "fixed", vertices: [0] }]).validate()).toMatch(/No handle/);
    expect(new GroupSet(3, [{ role: "handle", vertices: [0] }]).validate()).toMatch(/No fixed/);
    expect(new GroupSet(3, [{ role: "handle", vertices: [0] }, { role: "handle", vertices: [2] }]).validate()).toBeNull();
  });

  it("numbers groups per role for labels and colours", () => {
    const g = new GroupSet(4, [
      { role: "handle", vertices: [0] },
      { role: "fixed", vertices: [1] },
      { role: "handle", vertices: [2] },
    ]);
    expect([0, 1, 2].map((i) => g.ordinal(i))).toEqual([0, 0, 1]);
    expect(groupColor("handle", 0)).toEqual(HANDLE_COLORS[0]);
    expect(groupColor("handle", HANDLE_COLORS.length)).toEqual(HANDLE_COLORS[0]);
    expect(groupColor("fixed", 3)).not.toEqual(HANDLE_COLORS[0]);
  });
});
