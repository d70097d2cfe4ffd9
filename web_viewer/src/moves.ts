// The absolute state of the handle group, as the viewer's drag/gizmo/undo see it.
import { create } from "@bufbuild/protobuf";
import { GroupMoveSchema, QuaternionSchema, Vec3Schema, type GroupMove } from "./gen/meshdeform/v1/deformation_pb";

export interface MoveState {
  translation: [number, number, number];
  rotation: [number, number, number, number]; // w, x, y, z
  scale: number;
}

export const IDENTITY: MoveState = { translation: [0, 0, 0], rotation: [1, 0, 0, 0], scale: 1 };

export function cloneMove(s: MoveState): MoveState {
  return { translation: [...s.translation], rotation: [...s.rotation], scale: s.scale };
}

/** Rounded key so that float noise from the gizmo does not trigger re-sends. */
export function moveKey(s: MoveState): string {
  const r = (x: number) => x.toFixed(7);
  return [...s.translation, ...s.rotation, s.scale].map(r).join(",");
}

export function toGroupMove(group: number, s: MoveState, pivot: [number, number, number]): GroupMove {
  return create(GroupMoveSchema, {
    group,
    translation: create(Vec3Schema, { x: s.translation[0], y: s.translation[1], z: s.translation[2] }),
    rotation: create(QuaternionSchema, { w: s.rotation[0], x: s.rotation[1], y: s.rotation[2], z: s.rotation[3] }),
    scale: s.scale,
    pivot: create(Vec3Schema, { x: pivot[0], y: pivot[1], z: pivot[2] }),
  });
}

export type Vec3 = [number, number, number];
export type Quat = [number, number, number, number]; // w, x, y, z

/** Hamilton product a * b (apply b first, then a). */
export function quatMul(a: Quat, b: Quat): Quat {
  const [aw, ax, ay, az] = a, [bw, bx, by, bz] = b;
  return [
    aw * bw - ax * bx - ay * by - az * bz,
    aw * bx + ax * bw + ay * bz - az * by,
    aw * by - ax * bz + ay * bw + az * bx,
    aw * bz + ax * by - ay * bx + az * bw,
  ];
}

/** Rotation of `degrees` about the unit `axis`. */
export function axisAngle(axis: Vec3, degrees: number): Quat {
  const n = Math.hypot(axis[0], axis[1], axis[2]) || 1;
  const h = (degrees * Math.PI) / 360;
  const s = Math.sin(h) / n;
  return [Math.cos(h), axis[0] * s, axis[1] * s, axis[2] * s];
}

export function rotate(q: Quat, v: Vec3): Vec3 {
  const r = quatMul(quatMul(q, [0, v[0], v[1], v[2]]), [q[0], -q[1], -q[2], -q[3]]);
  return [r[1], r[2], r[3]];
}

/** The server's target of an anchor: pivot + scale * R * (anchor - pivot) + translation. */
export function applyMove(s: MoveState, pivot: Vec3, anchor: Vec3): Vec3 {
  const r = rotate(s.rotation, [anchor[0] - pivot[0], anchor[1] - pivot[1], anchor[2] - pivot[2]]);
  return [pivot[0] + s.scale * r[0] + s.translation[0], pivot[1] + s.scale * r[1] + s.translation[1], pivot[2] + s.scale * r[2] + s.translation[2]];
}

export const AXES: Record<"x" | "y" | "z", Vec3> = { x: [1, 0, 0], y: [0, 1, 0], z: [0, 0, 1] };

/**
 * Composes a numeric command with a group's state, about the group's current centre (pivot +
 * translation): translate adds `value` along `axis`; rotate turns by `value` degrees about `axis`;
 * scale multiplies the scale by `value`. The pivot is unchanged, so the result stays absolute.
 */
export function composeCommand(s: MoveState, kind: "translate" | "rotate" | "scale", axis: Vec3, value: number): MoveState {
  const out = cloneMove(s);
  if (kind === "translate") {
    const n = Math.hypot(axis[0], axis[1], axis[2]) || 1;
    out.translation = [s.translation[0] + (axis[0] / n) * value, s.translation[1] + (axis[1] / n) * value, s.translation[2] + (axis[2] / n) * value];
  } else if (kind === "rotate") {
    // p + Q(c + sR(a - c) + t - p) with p = c + t is c + s(QR)(a - c) + t.
    const q = quatMul(axisAngle(axis, value), s.rotation);
    const n = Math.hypot(...q);
    out.rotation = [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
  } else {
    out.scale = s.scale * value;
  }
  return out;
}

/** Every group's state (identity for fixed groups), as one undo entry. */
export type GroupStates = MoveState[];

export function identityStates(count: number): GroupStates {
  return Array.from({ length: count }, () => cloneMove(IDENTITY));
}

export function cloneStates(s: GroupStates): GroupStates {
  return s.map(cloneMove);
}

export function statesKey(s: GroupStates): string {
  return s.map(moveKey).join(";");
}

export function isIdentity(s: MoveState): boolean {
  return moveKey(s) === moveKey(IDENTITY);
}

/**
 * How "Reset to rest" gets the mesh back to its rest pose:
 * - "identity": the groups' anchors are the rest positions (handles were set on the rest mesh), so
 *   identity moves target the rest pose exactly;
 * - "rest-targets": the anchors are a deformed shape, so the constrained vertices are sent to their
 *   rest positions explicitly and the groups are set again there;
 * - "unavailable": the rest mesh is not known (the server no longer kept revision 0).
 * Either way the solve uses the Laplacian method: one direct solve with no warm start, whose
 * solution for rest targets is the rest mesh itself.
 */
export function planReset(restKnown: boolean, anchorsAtRest: boolean): "identity" | "rest-targets" | "unavailable" {
  if (anchorsAtRest) return "identity";
  return restKnown ? "rest-targets" : "unavailable";
}
