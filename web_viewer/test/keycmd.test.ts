import { describe, expect, it } from "vitest";
import { describeCommand, effectiveAxis, feedKey, startCommand, typedValue, type KeyCommand, type Step } from "../src/keycmd";

function type(keys: string[], start = "g"): Step {
  let cmd = startCommand(start) as KeyCommand;
  let step: Step = { state: "editing", cmd };
  for (const k of keys) {
    if (step.state !== "editing") break;
    step = feedKey(step.cmd, k);
  }
  return step;
}

describe("modal commands (G / R / S)", () => {
  it("start on G, R, S only", () => {
    expect(startCommand("g")?.kind).toBe("translate");
    expect(startCommand("R")?.kind).toBe("rotate");
    expect(startCommand("s")?.kind).toBe("scale");
    expect(startCommand("w")).toBeNull();
    expect(startCommand("Shift")).toBeNull();
  });

  it("G X 0.5 Enter moves along X by 0.5", () => {
    const s = type(["x", "0", ".", "5", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "translate", axis: "x", value: 0.5 });
  });

  it("Enter with nothing typed confirms the pointer's transform", () => {
    expect(type(["Enter"]).state === "apply" && (type(["Enter"]) as { resolved: unknown }).resolved).toEqual({ ok: true, kind: "translate", axis: null, value: null });
    const r = type(["z", "Enter"], "r");
    expect(r.state === "apply" && r.resolved).toEqual({ ok: true, kind: "rotate", axis: "z", value: null });
  });

  it("G 1 Enter without an axis moves along X (Blender's rule) and closes the command", () => {
    const s = type(["1", "Enter"]);
    expect(s.state).toBe("apply");
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "translate", axis: "x", value: 1 });
  });

  it("a new command never keeps the digits of the last one (the stale-digit bug)", () => {
    // G 1, then R Y 4 5: rotate about Y by 45, not 145.
    const s = type(["1", "r", "y", "4", "5", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "rotate", axis: "y", value: 45 });
    // The axis of the last command does not carry over either.
    const t = type(["x", "2", "g", "3", "Enter"]);
    expect(t.state === "apply" && t.resolved).toEqual({ ok: true, kind: "translate", axis: "x", value: 3 });
    const u = type(["z", "2", "s"]);
    expect(u.state === "editing" && u.cmd).toEqual({ kind: "scale", axis: null, text: "", note: "" });
  });

  it("accepts the number before the axis, a sign toggle and backspace", () => {
    const s = type(["1", "2", "Backspace", "-", "Y", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "translate", axis: "y", value: -1 });
  });

  it("a leading dot reads as 0.", () => {
    const s = type(["z", ".", "2", "5", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "translate", axis: "z", value: 0.25 });
  });

  it("pressing the same axis twice unlocks it", () => {
    const s = type(["x", "x"]);
    expect(s.state === "editing" && s.cmd.axis).toBeNull();
  });

  it("a lone minus is no amount yet; Esc cancels", () => {
    const s = type(["-"]);
    expect(s.state === "editing" && typedValue(s.cmd)).toBeNull();
    expect(type(["x", "3", "Escape"]).state).toBe("cancel");
  });

  it("the effective axis: typed moves default to X, pointer moves and rotations have none", () => {
    expect(effectiveAxis({ kind: "translate", axis: null, text: "", note: "" })).toBeNull();
    expect(effectiveAxis({ kind: "translate", axis: null, text: "2", note: "" })).toBe("x");
    expect(effectiveAxis({ kind: "rotate", axis: null, text: "2", note: "" })).toBeNull();
  });

  it("scale refuses axis locks and non-positive factors", () => {
    let s = type(["x"], "s");
    expect(s.state === "editing" && s.cmd.axis).toBeNull();
    expect(s.state === "editing" && s.cmd.note).toMatch(/uniform/);
    s = type(["-", "2", "Enter"], "s");
    expect(s.state === "editing" && s.cmd.note).toMatch(/greater than 0/);
    s = type(["1", ".", "5", "Enter"], "s");
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "scale", axis: null, value: 1.5 });
  });

  it("ignores other keys", () => {
    const s = type(["q", "z", "4", "5", "Enter"], "r");
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "rotate", axis: "z", value: 45 });
  });

  it("describes the command for the overlay", () => {
    const s = type(["x", "2"]);
    expect(s.state === "editing" && describeCommand(s.cmd)).toMatch(/^Move along X: 2 units — type a number, Enter or click confirms, Esc or right-click cancels$/);
    const free = type([]);
    expect(free.state === "editing" && describeCommand(free.cmd, "0.25 units")).toMatch(/^Move \(follows the pointer; X, Y or Z locks an axis\): 0.25 units/);
    const noAxis = type(["3"]);
    expect(noAxis.state === "editing" && describeCommand(noAxis.cmd)).toMatch(/^Move along X: 3 units \(no axis typed: X\)/);
  });
});
