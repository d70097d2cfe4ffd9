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
