import { describe, expect, it } from "vitest";
import { isTyping, onKey, type KeysHost } from "../src/app/keys";

describe("keys typed into a field", () => {
  it("belong to text fields, selects and text areas", () => {
    expect(isTyping({ tagName: "INPUT", type: "text" })).toBe(true);
    expect(isTyping({ tagName: "INPUT", type: "number" })).toBe(true);
    expect(isTyping({ tagName: "SELECT" })).toBe(true);
    expect(isTyping({ tagName: "TEXTAREA" })).toBe(true);
  });
  it("do not belong to sliders, checkboxes or anything else", () => {
    expect(isTyping({ tagName: "INPUT", type: "range" })).toBe(false);
    expect(isTyping({ tagName: "INPUT", type: "checkbox" })).toBe(false);
    expect(isTyping({ tagName: "CANVAS" })).toBe(false);
    expect(isTyping({ tagName: "BUTTON", type: "submit" })).toBe(false);
    expect(isTyping(null)).toBe(false);
  });
});

// A page whose calls are logged; the event is a plain object with the fields onKey reads.
function page(over: Partial<KeysHost> = {}, modalActive = false) {
  const log: string[] = [];
  const host: KeysHost = {
    modal: {
      get active() { return modalActive; },
      feed: (k) => log.push(`feed ${k}`),
      start: (k) => { log.push(`start ${k}`); return "gGrRsS".includes(k); },
    },
    undoRedo: (redo) => log.push(redo ? "redo" : "undo"),
    setView: (v) => log.push(`view ${v}`),
    frame: () => log.push("frame"),
    canEdit: () => true,
    selectedGroup: () => 2,
    deleteGroup: (i) => log.push(`delete ${i}`),
    ...over,
  };
  const press = (key: string, o: { code?: string; ctrl?: boolean; shift?: boolean; target?: object } = {}) => {
    let prevented = false;
    const e = {
      key, code: o.code ?? "", ctrlKey: !!o.ctrl, metaKey: false, altKey: false, shiftKey: !!o.shift,
      target: o.target ?? { tagName: "CANVAS" }, preventDefault: () => { prevented = true; },
    } as unknown as KeyboardEvent;
    onKey(e, host);
    return prevented;
  };
  return { log, press };
}

describe("the page's keys", () => {
  it("undo with Ctrl+Z, redo with Ctrl+Shift+Z or Ctrl+Y", () => {
    const { log, press } = page();
    expect(press("z", { ctrl: true })).toBe(true);
    expect(press("Z", { ctrl: true, shift: true })).toBe(true);
    expect(press("y", { ctrl: true })).toBe(true);
    expect(log).toEqual(["undo", "redo", "redo"]);
  });
  it("an open G / R / S command takes the keys first, Ctrl+Z aside", () => {
    const { log, press } = page({}, true);
    press("x");
    press("5");
    press("Enter");
    press("z", { ctrl: true });
    expect(log).toEqual(["feed x", "feed 5", "feed Enter", "undo"]);
  });
  it("F or Home frames the mesh; Del removes the selected group; G starts a command", () => {
    const { log, press } = page();
    press("f");
    press("Home");
    press("Delete");
    expect(press("g")).toBe(true);
    expect(press("q")).toBe(false); // not a command: left to the browser
    expect(log).toEqual(["frame", "frame", "delete 2", "start g", "start q"]);
  });
  it("a watcher's page (no editing) neither deletes nor starts commands", () => {
    const { log, press } = page({ canEdit: () => false });
    press("Delete");
    press("g");
    expect(log).toEqual([]);
  });
  it("keys typed into a text field are the field's", () => {
    const { log, press } = page();
    expect(press("z", { ctrl: true, target: { tagName: "INPUT", type: "text" } })).toBe(false);
    expect(press("f", { target: { tagName: "SELECT" } })).toBe(false);
    expect(log).toEqual([]);
  });
});
