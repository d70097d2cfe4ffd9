// What the page's parts share: the error banner, the test hooks, the undo timeline, the move
// coalescer, the open session, the 3D view and the applied group moves. main.ts builds one
// PageState and hands it to each part that needs all of it, beside that part's own callbacks.
import type { MoveHandlesResponse } from "../gen/meshdeform/v1/deformation_pb";
import type { MoveCoalescer } from "../coalescer";
import type { GroupStates } from "../moves";
import type { Viewer3D } from "../scene";
import type { Hooks } from "../test_hooks";
import type { Timeline } from "../timeline";
import type { Banner } from "../ui/dom";
import type { MoveTarget, Session } from "./session";

export interface PageState {
  readonly banner: Banner;
  /** The test hooks (window.__meshdeform). */
  readonly hooks: Hooks;
  readonly timeline: Timeline;
  readonly coalescer: MoveCoalescer<MoveTarget, MoveHandlesResponse>;
  session(): Session | null;
  viewer(): Viewer3D;
  /** Every applied group's move, as the page holds it (read and replaced). */
  states(): GroupStates;
  setStates(states: GroupStates): void;
}
