// The amount of a modal transform (G / R / S, src/keycmd.ts) from the pointer or a typed number,
// composed with the group's state at the command's start. Pure: app/modal_transform.ts supplies
// the screen and world quantities (where the pointer started and is now, the group's centre on
// screen, the pointer's travel on the plane through the group's centre facing the camera).
import type { Axis, CommandKind } from "./keycmd";
import { AXES, composeCommand, translateBy, type MoveState, type Vec3 } from "./moves";

export interface ModalPointer {
  /** The group's centre, where the pointer started and where it is now (screen pixels, y down). */
  centre: [number, number];
  start: [number, number];
  now: [number, number];
  /** The pointer's travel on the plane through the group's centre facing the camera (world). */
  planeDelta: Vec3;
  /** Unit vector from the scene towards the viewer (the view axis). */
  towardViewer: Vec3;
}

export interface ModalAmount {
  state: MoveState;
  /** For the overlay: "0.123 units", "45.0°", "×1.20". */
  label: string;
}

const dot = (a: Vec3, b: Vec3) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

/** Counter-clockwise screen angle (degrees, in (-180, 180]) from `start` to `now` about `centre`. */
export function screenAngle(centre: [number, number], start: [number, number], now: [number, number]): number {
  // Screen y points down: the visual counter-clockwise turn is the negative of atan2's.
  const a0 = Math.atan2(start[1] - centre[1], start[0] - centre[0]);
  const a1 = Math.atan2(now[1] - centre[1], now[0] - centre[0]);
  let d = -((a1 - a0) * 180) / Math.PI;
  while (d > 180) d -= 360;
  while (d <= -180) d += 360;
  return d;
}

/** The pointer's distance from the centre now over at the start (at least 1 px each). */
export function screenScale(centre: [number, number], start: [number, number], now: [number, number]): number {
  const d0 = Math.max(1, Math.hypot(start[0] - centre[0], start[1] - centre[1]));
  const d1 = Math.max(1, Math.hypot(now[0] - centre[0], now[1] - centre[1]));
  return d1 / d0;
}

/**
 * The group's state for a modal command: `base` (the state when the command started) with the
 * typed amount `value`, or with the pointer's when `value` is null. A rotation about a world axis
 * follows the pointer as seen: its sign flips when the axis points away from the viewer.
 */
export function modalState(base: MoveState, kind: CommandKind, axis: Axis | null, value: number | null, p: ModalPointer): ModalAmount {
  const ax = axis ? AXES[axis] : null;
  if (kind === "translate") {
    if (value !== null) return { state: composeCommand(base, "translate", ax ?? AXES.x, value), label: `${value} units` };
    const d = ax ? ax.map((c) => c * dot(p.planeDelta, ax)) as Vec3 : p.planeDelta;
    return { state: translateBy(base, d), label: `${Math.hypot(...d).toPrecision(3)} units` };
  }
  if (kind === "rotate") {
    const about = ax ?? p.towardViewer;
    if (value !== null) return { state: composeCommand(base, "rotate", about, value), label: `${value}°` };
    const sign = ax && dot(ax, p.towardViewer) < 0 ? -1 : 1;
    const deg = sign * screenAngle(p.centre, p.start, p.now);
    return { state: composeCommand(base, "rotate", about, deg), label: `${deg.toFixed(1)}°` };
  }
  const f = value !== null ? value : screenScale(p.centre, p.start, p.now);
  return { state: composeCommand(base, "scale", AXES.x, f), label: `${f.toFixed(3)}` };
}
