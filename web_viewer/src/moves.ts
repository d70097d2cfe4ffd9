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

/** The gizmo's scale made uniform: of its three axes' scales, the one the user pulled (the
 * largest change from the group's scale `prev`; `prev` when none changed), at least 0.05. */
export function pulledScale(prev: number, axes: readonly number[]): number {
  const sc = axes.reduce((a, b) => (Math.abs(b - prev) > Math.abs(a - prev) ? b : a), prev);
  return Math.max(0.05, sc);
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

/** Eigen-decomposition of a symmetric 4 x 4 matrix (cyclic Jacobi): the eigenvector of the
 * largest eigenvalue. */
function largestEigenvector4(m: number[][]): Quat {
  const a = m.map((r) => [...r]);
  const v = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]];
  for (let sweep = 0; sweep < 50; sweep++) {
    let off = 0;
    for (let p = 0; p < 4; p++) for (let q = p + 1; q < 4; q++) off += a[p][q] * a[p][q];
    if (off < 1e-30) break;
    for (let p = 0; p < 4; p++) {
      for (let q = p + 1; q < 4; q++) {
        if (Math.abs(a[p][q]) < 1e-300) continue;
        const theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
        const t = Math.sign(theta || 1) / (Math.abs(theta) + Math.sqrt(theta * theta + 1));
        const c = 1 / Math.sqrt(t * t + 1), s = t * c;
        for (let k = 0; k < 4; k++) {
          const akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (let k = 0; k < 4; k++) {
          const apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (let k = 0; k < 4; k++) {
          const vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
  let best = 0;
  for (let i = 1; i < 4; i++) if (a[i][i] > a[best][best]) best = i;
  const q: Quat = [v[0][best], v[1][best], v[2][best], v[3][best]];
  const n = Math.hypot(...q) || 1;
  const sign = q[0] < 0 ? -1 : 1;
  return [(sign * q[0]) / n, (sign * q[1]) / n, (sign * q[2]) / n, (sign * q[3]) / n];
}

/**
 * The similarity about the centroid of `from` that takes `from` closest to `to` (least squares;
 * Horn's quaternion method with Umeyama's scale): rows of 3, the same count. Re-expresses a
 * group's targets on other anchors (an undo across a handle change: the groups were set again
 * on another shape). One point: a translation only.
 */
export function fitSimilarity(from: ArrayLike<number>, to: ArrayLike<number>): MoveState {
  const n = Math.min(from.length, to.length) / 3;
  if (n === 0) return cloneMove(IDENTITY);
  const ca: Vec3 = [0, 0, 0], cb: Vec3 = [0, 0, 0];
  for (let i = 0; i < n; i++) for (let c = 0; c < 3; c++) { ca[c] += from[i * 3 + c] / n; cb[c] += to[i * 3 + c] / n; }
  const translation: Vec3 = [cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]];
  if (n === 1) return { translation, rotation: [1, 0, 0, 0], scale: 1 };
  const S = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
  let normA = 0;
  for (let i = 0; i < n; i++) {
    const a = [from[i * 3] - ca[0], from[i * 3 + 1] - ca[1], from[i * 3 + 2] - ca[2]];
    const b = [to[i * 3] - cb[0], to[i * 3 + 1] - cb[1], to[i * 3 + 2] - cb[2]];
    normA += a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
    for (let r = 0; r < 3; r++) for (let c = 0; c < 3; c++) S[r][c] += a[r] * b[c];
  }
  if (normA < 1e-30) return { translation, rotation: [1, 0, 0, 0], scale: 1 };
  const [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = S;
  const N = [
    [xx + yy + zz, yz - zy, zx - xz, xy - yx],
    [yz - zy, xx - yy - zz, xy + yx, zx + xz],
    [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
    [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
  ];
  const rotation = largestEigenvector4(N);
  let dot = 0;
  for (let i = 0; i < n; i++) {
    const ra = rotate(rotation, [from[i * 3] - ca[0], from[i * 3 + 1] - ca[1], from[i * 3 + 2] - ca[2]]);
    dot += ra[0] * (to[i * 3] - cb[0]) + ra[1] * (to[i * 3 + 1] - cb[1]) + ra[2] * (to[i * 3 + 2] - cb[2]);
  }
  const scale = dot > 0 ? dot / normA : 1;
  return { translation, rotation, scale };
}

/** Translation by `delta` composed with a group's state (about its current centre). */
export function translateBy(s: MoveState, delta: Vec3): MoveState {
  const out = cloneMove(s);
  out.translation = [s.translation[0] + delta[0], s.translation[1] + delta[1], s.translation[2] + delta[2]];
  return out;
}
