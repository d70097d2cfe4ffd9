import { describe, expect, it } from "vitest";
import { applyMove, AXES, axisAngle, composeCommand, IDENTITY, isIdentity, quatMul, rotate, statesKey, identityStates, type Vec3 } from "../src/moves";

const close = (a: number[], b: number[], eps = 1e-12) => a.forEach((x, i) => expect(Math.abs(x - b[i])).toBeLessThan(eps));

describe("moves", () => {
  it("rotates with quaternions", () => {
    const q = axisAngle([0, 0, 1], 90);
    close(rotate(q, [1, 0, 0]), [0, 1, 0]);
    close(quatMul(q, q), axisAngle([0, 0, 1], 180));
  });

  it("translate adds along the axis", () => {
    const s = composeCommand(composeCommand(IDENTITY, "translate", AXES.x, 0.5), "translate", AXES.y, -2);
    expect(s.translation).toEqual([0.5, -2, 0]);
    expect(s.rotation).toEqual(IDENTITY.rotation);
    expect(s.scale).toBe(1);
  });

  it("rotate and scale act about the group's current centre", () => {
    const pivot: Vec3 = [1, 0, 0];
    const anchor: Vec3 = [2, 0, 0];
    let s = composeCommand(IDENTITY, "translate", AXES.z, 3); // centre now at (1, 0, 3)
    s = composeCommand(s, "rotate", AXES.z, 90);
    close(applyMove(s, pivot, anchor), [1, 1, 3]);
    close(applyMove(s, pivot, pivot), [1, 0, 3]); // the centre stays
    s = composeCommand(s, "scale", AXES.x, 2);
    close(applyMove(s, pivot, anchor), [1, 2, 3]);
    expect(s.scale).toBe(2);
  });

  it("the identity targets the anchors (up to double rounding)", () => {
    const a: Vec3 = [0.1, -7.25, 3.5];
    close(applyMove(IDENTITY, [4, 5, 6], a), a, 1e-15 * 8);
    expect(isIdentity(IDENTITY)).toBe(true);
    expect(isIdentity(composeCommand(IDENTITY, "scale", AXES.x, 1.01))).toBe(false);
  });

  it("keys all groups' states", () => {
    const a = identityStates(2);
    const b = identityStates(2);
    b[1] = composeCommand(b[1], "translate", AXES.x, 1);
    expect(statesKey(a)).toBe(statesKey(identityStates(2)));
    expect(statesKey(a)).not.toBe(statesKey(b));
  });
});

import { planReset } from "../src/moves";
describe("reset plan", () => {
  it("uses identity moves when the anchors are the rest pose", () => {
    expect(planReset(true, true)).toBe("identity");
    expect(planReset(false, true)).toBe("identity");
    expect(planReset(true, false)).toBe("rest-targets");
    expect(planReset(false, false)).toBe("unavailable");
  });
});

import { pulledScale } from "../src/moves";
describe("gizmo scale made uniform", () => {
  it("keeps the group's scale when no axis changed", () => {
    expect(pulledScale(1, [1, 1, 1])).toBe(1);
    expect(pulledScale(2.5, [2.5, 2.5, 2.5])).toBe(2.5);
  });
  it("takes the axis the user pulled, whichever it is", () => {
    expect(pulledScale(1, [1.5, 1, 1])).toBe(1.5);
    expect(pulledScale(1, [1, 0.75, 1])).toBe(0.75);
    expect(pulledScale(2, [2, 2, 3])).toBe(3);
  });
  it("takes the largest change from the group's scale, the first of equal ones", () => {
    expect(pulledScale(1, [1.2, 0.5, 1.1])).toBe(0.5);
    expect(pulledScale(1, [1.5, 0.5, 1])).toBe(1.5);
  });
  it("never goes below 0.05 (a collapsed or flipped axis)", () => {
    expect(pulledScale(1, [0.01, 1, 1])).toBe(0.05);
    expect(pulledScale(0.2, [0.2, -3, 0.2])).toBe(0.05);
    expect(pulledScale(0.04, [0.04, 0.04, 0.04])).toBe(0.05);
  });
});
