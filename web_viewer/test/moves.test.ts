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
