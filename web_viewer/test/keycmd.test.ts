import { describe, expect, it } from "vitest";
import { describeCommand, feedKey, startCommand, type KeyCommand, type Step } from "../src/keycmd";

function type(keys: string[], start = "g"): Step {
  let cmd = startCommand(start) as KeyCommand;
  let step: Step = { state: "editing", cmd };
  for (const k of keys) {
    if (step.state !== "editing") break;
    step = feedKey(step.cmd, k);
  }
  return step;
}

describe("key commands", () => {
  it("starts on G, R, S only", () => {
    expect(startCommand("g")?.kind).toBe("translate");
    expect(startCommand("R")?.kind).toBe("rotate");
    expect(startCommand("s")?.kind).toBe("scale");
    expect(startCommand("w")).toBeNull();
  });

  it("G X 0.5 Enter moves along X by 0.5", () => {
    const s = type(["x", "0", ".", "5", "Enter"]);
    expect(s.state).toBe("apply");
    if (s.state === "apply") expect(s.resolved).toEqual({ ok: true, kind: "translate", axis: "x", value: 0.5 });
  });

  it("accepts the number before the axis, a sign toggle and backspace", () => {
    const s = type(["1", "2", "Backspace", "-", "Y", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "translate", axis: "y", value: -1 });
  });

  it("a leading dot reads as 0.", () => {
    const s = type(["z", ".", "2", "5", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "translate", axis: "z", value: 0.25 });
  });

  it("pressing the same axis twice unlocks it; translate then needs an axis", () => {
    const s = type(["x", "x", "1", "Enter"]);
    expect(s.state).toBe("editing");
    if (s.state === "editing") {
      expect(s.cmd.axis).toBeNull();
      expect(s.cmd.note).toMatch(/axis/);
    }
  });

  it("Enter without a number keeps editing; Esc cancels", () => {
    const s = type(["x", "Enter"]);
    expect(s.state === "editing" && s.cmd.note).toMatch(/number/);
    expect(type(["x", "3", "Escape"]).state).toBe("cancel");
  });

  it("rotation without an axis is about the view axis", () => {
    const s = type(["9", "0", "Enter"], "r");
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "rotate", axis: null, value: 90 });
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

  it("switches kind with G/R/S and ignores other keys", () => {
    const s = type(["r", "q", "z", "4", "5", "Enter"]);
    expect(s.state === "apply" && s.resolved).toEqual({ ok: true, kind: "rotate", axis: "z", value: 45 });
  });

  it("describes the command for the overlay", () => {
    const s = type(["x", "2"]);
    expect(s.state === "editing" && describeCommand(s.cmd)).toMatch(/^Move along X: 2 units — Enter applies, Esc cancels$/);
  });
});
