// What the page holds for one open session, and the moves it sends.
import * as THREE from "three";
import type { HandleGroup } from "../gen/meshdeform/v1/deformation_pb";
import type { GroupSet } from "../groups";
import type { GroupStates } from "../moves";
import type { Adjacency } from "../pick";
import type { SelectionState } from "../selection";
import type { Credentials } from "../share";
import type { Role } from "../test_hooks";
import type { Entry } from "../timeline";
import type { PositionState } from "../updates";
import type { HeatMetric } from "../frames";

export interface MoveTarget {
  states: GroupStates;
  t0: number;
  opts: string;
  /** The drag this move belongs to (its moves make one undo step); 0n: a step of its own. */
  gesture: bigint;
  /** The history entry this move makes (its server step is filled in from the response). */
  entry: Entry | null;
}

/** Per applied group: where its vertices were when the handles were set (the server's anchors, as
 * rendered) and their centroid (the pivot of the group's rotation and scale). */
export interface Anchor {
  centroid: THREE.Vector3 | null;
  positions: Float32Array;
}

/** A pick-and-drag whose handles are being set while the pointer already moves. */
export interface PendingPick {
  delta: THREE.Vector3 | null;
  t0: number;
  applied: boolean;
  released: boolean;
  failed: boolean;
}

/** Everything that belongs to one open session. */
export interface Session {
  creds: Credentials;
  role: Role;
  viewToken: string | null;
  editToken: string | null;
  indices: Uint32Array;
  /** Revision 0 as loaded; restKnown false if the server no longer had it (then it is the shape at opening). */
  rest: Float32Array;
  restKnown: boolean;
  /** The positions on screen and their revision (the worker's last frame). */
  state: PositionState;
  selection: SelectionState; // the magnify region
  draft: GroupSet; // the groups as painted
  groups: HandleGroup[]; // the groups as applied (SetHandles)
  anchors: Anchor[];
  /** The applied groups' anchors are the rest positions: identity moves give the rest pose. */
  anchorsAtRest: boolean;
  gone: boolean;
  worker: Worker | null;
  gotSnapshot: Promise<void>;
  resolveSnapshot: () => void;
  /** The heat map's values of the last frame (radians or |log ratio|) and their metric. */
  heat: Float32Array | null;
  heatMetric: HeatMetric | null;
  topology: { adjacency: Adjacency; components: { id: Int32Array; count: number } } | null;
}

/** The centroid of 3-per-vertex rows, or null for none. */
export function centroidOfRows(a: ArrayLike<number>): THREE.Vector3 | null {
  const n = a.length / 3;
  if (n === 0) return null;
  const c = new THREE.Vector3();
  for (let k = 0; k < n; k++) c.add(new THREE.Vector3(a[k * 3], a[k * 3 + 1], a[k * 3 + 2]));
  return c.divideScalar(n);
}
