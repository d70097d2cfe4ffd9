import { describe, expect, it } from "vitest";
import { UndoStack } from "../src/history";
import { IDENTITY, moveKey, type MoveState } from "../src/moves";

const t = (x: number): MoveState => ({ ...IDENTITY, translation: [x, 0, 0] });

describe("UndoStack", () => {
  it("undoes and redoes absolute states", () => {
    const s = new UndoStack<MoveState>(IDENTITY);
    expect(s.canUndo).toBe(false);
    s.push(t(1));
    s.push(t(2));
    expect(s.undo()).toEqual(t(1));
    expect(s.undo()).toEqual(IDENTITY);
    expect(s.undo()).toBeNull();
    expect(s.redo()).toEqual(t(1));
    expect(s.current).toEqual(t(1));
  });
  it("drops the redo branch on a new push and ignores duplicates", () => {
    const s = new UndoStack<MoveState>(IDENTITY);
    s.push(t(1));
    s.push(t(2));
    s.undo();
    s.push(t(3));
    expect(s.canRedo).toBe(false);
    s.push(t(3));
    expect(s.undo()).toEqual(t(1));
  });
  it("resets on handle changes", () => {
    const s = new UndoStack<MoveState>(IDENTITY);
    s.push(t(1));
    s.reset();
    expect(s.canUndo).toBe(false);
    expect(s.current).toEqual(IDENTITY);
  });
  it("keys moves stably despite float noise", () => {
    expect(moveKey(t(1))).toBe(moveKey(t(1 + 1e-12)));
    expect(moveKey(t(1))).not.toBe(moveKey(t(1.001)));
  });
  it("restores a stored history and keeps at most its limit", () => {
    const s = new UndoStack<MoveState>(IDENTITY, 3);
    s.restore([IDENTITY, t(1), t(2)], 1);
    expect(s.current).toEqual(t(1));
    expect(s.redo()).toEqual(t(2));
    s.push(t(3)); // drops the oldest
    expect(s.undo()).toEqual(t(2));
    expect(s.undo()).toEqual(t(1));
    expect(s.undo()).toBeNull();
    s.restore([IDENTITY, t(1), t(2), t(3), t(4)], 4);
    expect(s.current).toEqual(t(4));
    expect(s.undo()).toEqual(t(3));
    expect(s.undo()).toEqual(t(2));
    expect(s.canUndo).toBe(false);
  });
});
