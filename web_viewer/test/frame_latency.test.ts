import { describe, expect, it } from "vitest";
import { DragToFrame } from "../src/frame_latency";

describe("DragToFrame", () => {
  it("matches a move's answer and its revision's first frame in either order", () => {
    const out: number[] = [];
    const d = new DragToFrame(out);
    d.answered(5, 100, 4); // answer first: waits for revision 5's frame
    d.drawn(5, 180);
    expect(out).toEqual([80]);
    d.drawn(6, 300); // frame first (the Watch stream was quicker than the answer)
    d.answered(6, 250, 6);
    expect(out).toEqual([80, 50]);
    expect(d.waiting).toBe(0);
  });

  it("counts only the first frame of a revision, and never a revision already passed", () => {
    const out: number[] = [];
    const d = new DragToFrame(out);
    d.answered(3, 0, 7); // revision 7 is on screen: 3's frame will never come
    expect(d.waiting).toBe(0);
    d.answered(8, 10, 7);
    d.drawn(8, 40);
    d.drawn(8, 90); // a redraw of the same revision
    expect(out).toEqual([30]);
  });

  it("forgets unmatched revisions far behind the newest frame", () => {
    const d = new DragToFrame([]);
    for (let r = 1; r <= 10; r++) d.answered(r, r, 0); // answers whose frames were dropped
    d.drawn(100, 1000);
    expect(d.waiting).toBe(1); // only revision 100's frame, waiting for its answer
  });
});
