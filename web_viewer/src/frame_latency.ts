// Drag to frame (Hooks.metrics().dragToFrameMs): from the pointer event a move was made of to the
// end of the first frame that shows the revision it produced. A move's answer and its revision's
// first frame come in either order (geometry comes from the Watch stream, the answer from
// MoveHandles), so whichever comes first waits here for the other. Pure.

/** How far behind the newest frame an unmatched revision is forgotten (it will never match). */
const KEEP_REVISIONS = 64;

export class DragToFrame {
  private readonly moveT0 = new Map<number, number>(); // revision -> pointer time
  private readonly frameAt = new Map<number, number>(); // revision -> end of its first frame

  /** @param out where each matched delay (ms) is appended. */
  constructor(private readonly out: number[]) {}

  /** A move made at pointer time `t0` produced revision `rev`; `shown` is the revision on
   * screen now (an older revision's frame is still to come, a newer one never will). */
  answered(rev: number, t0: number, shown: number): void {
    const done = this.frameAt.get(rev);
    if (done !== undefined) {
      this.out.push(done - t0);
      this.frameAt.delete(rev);
    } else if (rev > shown) {
      this.moveT0.set(rev, t0);
    }
  }

  /** The first frame showing revision `rev` ended at `now`. */
  drawn(rev: number, now: number): void {
    const t0 = this.moveT0.get(rev);
    if (t0 !== undefined) {
      this.out.push(now - t0);
      this.moveT0.delete(rev);
    } else {
      this.frameAt.set(rev, now);
    }
    for (const m of [this.frameAt, this.moveT0]) for (const k of m.keys()) if (k < rev - KEEP_REVISIONS) m.delete(k);
  }

  /** Revisions waiting for their other half (for tests). */
  get waiting(): number {
    return this.moveT0.size + this.frameAt.size;
  }
}
