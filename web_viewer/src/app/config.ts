// The page's settings from its address (?encoding=, ?updates=, ?coarse=, ?lambda=, ?sample=)
// and the constants the page's wiring shares.
import { MeshFormat } from "../gen/meshdeform/v1/deformation_pb";
import { makeClient } from "../client";
import { parseEncoding } from "../updates";
import { linkSizedOptions, parseLinkSized } from "../update_codec";

export const query = new URLSearchParams(location.search);
/** localStorage, or null where the browser refuses it (privacy settings, sandboxed frames). */
export function storage(): Storage | null {
  try {
    return window.localStorage;
  } catch {
    return null;
  }
}

export const ENCODING = parseEncoding(query.get("encoding"));
// ?updates=quantized|lossless[&tolerance=X][&budget=BYTES]: link-sized Watch updates (issue 45).
export const LINK_SIZED = parseLinkSized(query);
export const UPDATES = linkSizedOptions(LINK_SIZED);
// ?coarse=on|off: draw the coarse level during a multiresolution drag (an editor's page only: a
// watcher draws the full mesh, so its stream does not carry the level). Default on, except with
// link-sized updates: the level's float32 positions (12 bytes per coarse vertex) would come on
// top of their byte budget.
export const COARSE = query.get("coarse") === "on" || (query.get("coarse") !== "off" && UPDATES === undefined);
export const client = makeClient(location.origin);
// ?lambda= soft handle weight for new sessions (server default 100 lets fixed vertices drift ~1e-4).
export const LAMBDA = Number(query.get("lambda")) > 0 ? Number(query.get("lambda")) : undefined;
export const FORMATS: Record<string, MeshFormat> = {
  obj: MeshFormat.OBJ, off: MeshFormat.OFF, ply: MeshFormat.PLY, stl: MeshFormat.STL, glb: MeshFormat.GLB, gltf: MeshFormat.GLTF,
};
/** Controls that edit the session (disabled for watchers and once the session is gone). */
export const EDIT_CONTROLS = ["tool-move", "tool-grab", "tool-brush", "tool-lasso", "gizmo-translate", "gizmo-rotate", "gizmo-scale", "apply-handles",
  "clear-selection", "extend-group", "paint-mode", "undo", "redo", "method", "ora", "rigidity", "iterations", "magnify", "delete-group",
  "reset-rest", "grab-radius"];
export const GONE_TEXT = "The session this link points to no longer exists: it was closed, it expired, or the server restarted. Its edits cannot be recovered from here.";
