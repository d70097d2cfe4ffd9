import { describe, expect, it } from "vitest";
import { defaultView, namedView, viewForKey } from "../src/views";

const dot = (a: number[], b: number[]) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

describe("views", () => {
  it("the opening view looks across the longest axis, from nearly horizontal", () => {
    for (const size of [[4, 1, 1], [1, 4, 1], [1, 1, 4], [3, 0.2, 2]] as [number, number, number][]) {
      const v = defaultView(size);
      const longest = size.indexOf(Math.max(...size));
      const axis = [0, 0, 0];
      axis[longest] = 1;
      expect(Math.abs(dot(v.eye, axis))).toBeLessThan(0.5); // not along it
      expect(Math.hypot(...v.eye)).toBeCloseTo(1);
      expect(v.eye[1]).toBeGreaterThan(0); // raised a little
      expect(v.eye[1]).toBeLessThan(0.5);
    }
  });
  it("the keys 1 / 3 / 7 (row or keypad) and Ctrl for the opposite", () => {
    expect(viewForKey("Digit1", "1", false)).toBe("front");
    expect(viewForKey("Numpad3", "3", false)).toBe("right");
    expect(viewForKey("Numpad7", "Home", false)).toBe("top");
    expect(viewForKey("Digit1", "1", true)).toBe("back");
    expect(viewForKey("KeyG", "g", false)).toBeNull();
    expect(namedView("top").eye[1]).toBeCloseTo(1);
    expect(namedView("right").eye).toEqual([1, 0, 0]);
  });
});
