// Camera directions (issue 44): the view a mesh opens with, looking across its longest axis so
// that a first drag bends it instead of pushing along it, and the front / side / top keys. World
// up is +Y (three.js's). Pure: the scene applies them.

export type Vec3 = [number, number, number];
export type ViewName = "front" | "back" | "right" | "left" | "top" | "bottom";

export interface ViewDir {
  /** Unit vector from the target towards the camera. */
  eye: Vec3;
  up: Vec3;
}

const norm = (v: Vec3): Vec3 => {
  const n = Math.hypot(...v) || 1;
  return [v[0] / n, v[1] / n, v[2] / n];
};

/** The axis views: front from +Z, right from +X, top from +Y (-Z up on screen: the camera sits a
 * hair in front of the pole, where the orbit controls keep it), and their opposites (Ctrl with
 * the key, as in Blender). */
export function namedView(name: ViewName): ViewDir {
  const up: Vec3 = [0, 1, 0];
  switch (name) {
    case "front": return { eye: [0, 0, 1], up };
    case "back": return { eye: [0, 0, -1], up };
    case "right": return { eye: [1, 0, 0], up };
    case "left": return { eye: [-1, 0, 0], up };
    case "top": return { eye: norm([0, 1, 1e-4]), up };
    case "bottom": return { eye: norm([0, -1, 1e-4]), up };
  }
}

/**
 * The opening view of a mesh with bounding box size `size`: the camera looks across the longest
 * axis from a horizontal direction (the other horizontal axis, or the shorter one when the
 * longest is vertical), raised and turned a little so that depth reads. A drag in the view plane
 * then bends the long axis rather than squashing it.
 */
export function defaultView(size: Vec3): ViewDir {
  const longest = size.indexOf(Math.max(...size));
  // Horizontal candidates: X (0) and Z (2).
  let across: 0 | 2;
  if (longest === 0) across = 2;
  else if (longest === 2) across = 0;
  else across = size[2] <= size[0] ? 2 : 0; // vertical long axis: look along the thinner side
  const eye: Vec3 = [0, 0, 0];
  eye[across] = 1;
  // Turn 20 degrees about Y (towards the other horizontal axis) and raise 20 degrees.
  const other = across === 2 ? 0 : 2;
  const turn = (20 * Math.PI) / 180, rise = (20 * Math.PI) / 180;
  const h: Vec3 = [0, 0, 0];
  h[across] = Math.cos(turn);
  h[other] = Math.sin(turn) * (across === 2 ? 1 : -1);
  return { eye: norm([h[0] * Math.cos(rise), Math.sin(rise), h[2] * Math.cos(rise)]), up: [0, 1, 0] };
}

/** Which named view a key press asks for (1 front, 3 right, 7 top, with Ctrl the opposite;
 * the number row and the keypad alike), or null. */
export function viewForKey(code: string, key: string, ctrl: boolean): ViewName | null {
  const k = code.startsWith("Numpad") ? code.slice(6) : code.startsWith("Digit") ? code.slice(5) : key;
  if (k === "1") return ctrl ? "back" : "front";
  if (k === "3") return ctrl ? "left" : "right";
  if (k === "7") return ctrl ? "bottom" : "top";
  return null;
}
