// The "iterations per move" field: a whole number the server accepts.

/** MoveHandlesRequest.max_iterations: the server refuses values outside [1, 1000]
 * (server/service/session.cpp, server/transport/proto_convert.cpp). */
export const MIN_ITERATIONS = 1;
export const MAX_ITERATIONS = 1000;
export const DEFAULT_ITERATIONS = 2;

export type Parsed = { ok: true; value: number } | { ok: false; reason: string };

export function parseIterations(text: string): Parsed {
  const t = text.trim();
  const range = `a whole number from ${MIN_ITERATIONS} to ${MAX_ITERATIONS}`;
  if (t === "") return { ok: false, reason: `Iterations: enter ${range}.` };
  if (!/^[+-]?\d+$/.test(t)) return { ok: false, reason: `Iterations must be ${range} (got “${t}”).` };
  const v = Number(t);
  if (v < MIN_ITERATIONS) return { ok: false, reason: `Iterations must be at least ${MIN_ITERATIONS} (got ${v}).` };
  if (v > MAX_ITERATIONS) return { ok: false, reason: `Iterations must be at most ${MAX_ITERATIONS}, the server's limit (got ${t}).` };
  return { ok: true, value: v };
}
