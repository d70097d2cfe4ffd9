// Blender-style modal transforms (issue 44): G (move), R (rotate) or S (scale) starts a free
// transform of the selected handle group that follows the pointer; X / Y / Z locks a world axis
// (the same axis again unlocks); a typed number replaces the pointer's amount; Enter or a click
// confirms, Esc or a right-click cancels. G, R or S while a command is open starts that command
// afresh, with an empty number (typed digits never carry over from one command to the next). A
// pure state machine: app/modal_transform.ts feeds it keys and the pointer's amount.

export type CommandKind = "translate" | "rotate" | "scale";
export type Axis = "x" | "y" | "z";

export interface KeyCommand {
  kind: CommandKind;
  axis: Axis | null;
  /** The number as typed ("", "-", "0.5", ...); empty: the pointer decides the amount. */
  text: string;
  /** A remark about the last key (e.g. why an axis was refused); "" when none. */
  note: string;
}

/** What Enter (or a click) confirms. `value` null: the pointer's transform; else the typed
 * amount (mesh units along `axis`, degrees about `axis`, or a scale factor). A typed move
 * without an axis is along X, as in Blender. */
export type Resolved =
  | { ok: true; kind: CommandKind; axis: Axis | null; value: number | null }
  | { ok: false; reason: string };

export type Step =
  | { state: "editing"; cmd: KeyCommand }
  | { state: "apply"; cmd: KeyCommand; resolved: Resolved & { ok: true } }
  | { state: "cancel" };

const KINDS: Record<string, CommandKind> = { g: "translate", r: "rotate", s: "scale" };

/** A new command for key G, R or S (any case), else null. */
export function startCommand(key: string): KeyCommand | null {
  const kind = KINDS[key.length === 1 ? key.toLowerCase() : ""];
  return kind ? { kind, axis: null, text: "", note: "" } : null;
}

/** Feeds one KeyboardEvent.key. Unknown keys leave the command as it is. */
export function feedKey(cmd: KeyCommand, key: string): Step {
  const c: KeyCommand = { ...cmd, note: "" };
  if (key === "Escape") return { state: "cancel" };
  if (key === "Enter" || key === "NumpadEnter") {
    const resolved = resolveCommand(c);
    return resolved.ok ? { state: "apply", cmd: c, resolved } : { state: "editing", cmd: { ...c, note: resolved.reason } };
  }
  const k = key.length === 1 ? key.toLowerCase() : key;
  if (k === "x" || k === "y" || k === "z") {
    if (c.kind === "scale") c.note = "Scale is uniform: a group moves by a similarity, so it has no axis lock.";
    else c.axis = c.axis === k ? null : k; // the same axis again unlocks
  } else if (KINDS[k]) {
    // A new command: its own kind, no axis, and no digits left over from the last one.
    return { state: "editing", cmd: { kind: KINDS[k], axis: null, text: "", note: "" } };
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

/** The typed amount, or null when nothing usable is typed yet ("" or "-"): the pointer's. */
export function typedValue(c: KeyCommand): number | null {
  if (c.text === "" || c.text === "-") return null;
  const v = Number(c.text);
  return Number.isFinite(v) ? v : null;
}

/** The axis a command uses: a typed move without one is along X (Blender's rule). */
export function effectiveAxis(c: KeyCommand): Axis | null {
  return c.axis ?? (c.kind === "translate" && typedValue(c) !== null ? "x" : null);
}

export function resolveCommand(c: KeyCommand): Resolved {
  const value = typedValue(c);
  if (c.text !== "" && c.text !== "-" && value === null) return { ok: false, reason: `“${c.text}” is not a number.` };
  if (c.kind === "scale" && value !== null && !(value > 0)) return { ok: false, reason: "A scale factor must be greater than 0." };
  return { ok: true, kind: c.kind, axis: effectiveAxis(c), value };
}

/** One line for the overlay, e.g. "Move along X: 0.5 units — Enter or click confirms, Esc or
 * right-click cancels". `pointer` describes the pointer's current amount when nothing is typed. */
export function describeCommand(c: KeyCommand, pointer = ""): string {
  const typed = typedValue(c) !== null || c.text === "-";
  const axis = effectiveAxis(c)?.toUpperCase() ?? null;
  const amount = typed ? c.text : pointer || "…";
  const what =
    c.kind === "translate"
      ? `Move${axis ? ` along ${axis}` : " (follows the pointer; X, Y or Z locks an axis)"}: ${amount}${typed ? " units" : ""}` +
        (typed && !c.axis ? " (no axis typed: X)" : "")
      : c.kind === "rotate"
        ? `Rotate about ${axis ?? "the view axis"}: ${amount}${typed ? "°" : ""}`
        : `Scale by ×${amount}`;
  return `${what} — type a number, Enter or click confirms, Esc or right-click cancels${c.note ? ` (${c.note})` : ""}`;
}
