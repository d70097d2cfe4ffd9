// Blender-style numeric entry: G (move), R (rotate), S (scale), then optionally X/Y/Z to lock an
// axis, then a number; Enter applies, Esc cancels. A pure state machine: main.ts feeds it keys.

export type CommandKind = "translate" | "rotate" | "scale";
export type Axis = "x" | "y" | "z";

export interface KeyCommand {
  kind: CommandKind;
  axis: Axis | null;
  /** The number as typed ("", "-", "0.5", ...). */
  text: string;
  /** A remark about the last key (e.g. why an axis was refused); "" when none. */
  note: string;
}

export type Resolved =
  | { ok: true; kind: CommandKind; axis: Axis | null; value: number }
  | { ok: false; reason: string };

export type Step =
  | { state: "editing"; cmd: KeyCommand }
  | { state: "apply"; cmd: KeyCommand; resolved: Resolved }
  | { state: "cancel" };

const KINDS: Record<string, CommandKind> = { g: "translate", r: "rotate", s: "scale" };

/** A new command for key G, R or S (any case), else null. */
export function startCommand(key: string): KeyCommand | null {
  const kind = KINDS[key.toLowerCase()];
  return kind ? { kind, axis: null, text: "", note: "" } : null;
}

/** Feeds one KeyboardEvent.key. Unknown keys leave the command as it is. */
export function feedKey(cmd: KeyCommand, key: string): Step {
  const c: KeyCommand = { ...cmd, note: "" };
  if (key === "Escape") return { state: "cancel" };
  if (key === "Enter") {
    const resolved = resolveCommand(c);
    return resolved.ok ? { state: "apply", cmd: c, resolved } : { state: "editing", cmd: { ...c, note: resolved.reason } };
  }
  const k = key.length === 1 ? key.toLowerCase() : key;
  if (k === "x" || k === "y" || k === "z") {
    if (c.kind === "scale") c.note = "Scale is uniform: a group moves by a similarity, so it has no axis lock.";
    else c.axis = c.axis === k ? null : k; // the same axis again unlocks
  } else if (KINDS[k]) {
    c.kind = KINDS[k];
    if (c.kind === "scale") c.axis = null;
  } else if (/^[0-9]$/.test(k)) {
    c.text += k;
  } else if (k === ".") {
    if (!c.text.includes(".")) c.text += c.text.replace("-", "") === "" ? "0." : ".";
  } else if (k === "-") {
    c.text = c.text.startsWith("-") ? c.text.slice(1) : "-" + c.text; // toggles the sign
  } else if (k === "Backspace") {
    c.text = c.text.slice(0, -1);
  }
  return { state: "editing", cmd: c };
}

export function resolveCommand(c: KeyCommand): Resolved {
  const t = c.text;
  if (t === "" || t === "-") return { ok: false, reason: "Type a number first." };
  const value = Number(t);
  if (!Number.isFinite(value)) return { ok: false, reason: `“${t}” is not a number.` };
  if (c.kind === "translate" && c.axis === null) return { ok: false, reason: "Choose an axis: X, Y or Z." };
  if (c.kind === "scale" && !(value > 0)) return { ok: false, reason: "A scale factor must be greater than 0." };
  return { ok: true, kind: c.kind, axis: c.axis, value };
}

/** One line for the status overlay, e.g. "Move along X: 0.5 — Enter applies, Esc cancels". */
export function describeCommand(c: KeyCommand): string {
  const axis = c.axis ? c.axis.toUpperCase() : null;
  const what =
    c.kind === "translate" ? `Move${axis ? ` along ${axis}` : " (press X, Y or Z)"}: ${c.text || "…"} units`
    : c.kind === "rotate" ? `Rotate about ${axis ?? "the view axis"}: ${c.text || "…"}°`
    : `Scale by ×${c.text || "…"}`;
  return `${what} — Enter applies, Esc cancels${c.note ? ` (${c.note})` : ""}`;
}
