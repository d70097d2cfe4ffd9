import { describe, expect, it } from "vitest";
import { FrameGate, type UpdateInfo } from "../src/frames";

const info = (revision: number): UpdateInfo => ({
  revision, bytes: 1, encoding: "meshopt", isSnapshot: false, refinement: false, converged: false, eTheta: 0, ePhi: 0,
  areaLogRms: 0, iterations: 1, pcgIterations: 0, solveSeconds: 0, appliedAt: 0,
});

describe("FrameGate", () => {
  it("sends one frame at a time and drops (never queues) the ones between", () => {
    const g = new FrameGate();
    expect(g.take()).toBeNull();
    g.update(info(1));
    expect(g.take()?.map((u) => u.revision)).toEqual([1]);
    // The page has not drawn it yet: updates 2..5 wait, applied, for one frame.
    for (let r = 2; r <= 5; r++) g.update(info(r));
    expect(g.take()).toBeNull();
    g.ack();
    expect(g.take()?.map((u) => u.revision)).toEqual([2, 3, 4, 5]);
    g.ack();
    expect(g.take()).toBeNull();
  });
  it("a heat map change sends a frame without an update", () => {
    const g = new FrameGate();
    g.heat();
    expect(g.take()).toEqual([]);
  });
});
