// Progress of CreateSession / SetHandles (their *WithProgress streams): the server's phases in
// words for the status line, and the reading of the stream (progress events, then the response).

/** A Progress message as the generated code has it. */
export interface ProgressLike {
  phase: string;
  fraction: number;
  elapsedSeconds: number;
}

/** The events of CreateSessionEvent / SetHandlesEvent (a oneof of progress or the response). */
export interface ProgressEvent<R> {
  event: { case: "progress"; value: ProgressLike } | { case: "response"; value: R } | { case: undefined; value?: undefined };
}

const PHASES: Record<string, string> = {
  queued: "waiting for a worker",
  parse: "reading the mesh",
  session: "preparing the session",
  validate: "checking the mesh",
  rigid_start: "factorizing the start",
  laplacian_guess: "factorizing the Laplacian start",
  step_two: "factorizing the solver",
  factorize: "factorizing",
  decimate: "building the coarse level",
  prolongation: "building the detail transfer",
  coarse_precompute: "factorizing the coarse level",
  fine_precompute: "factorizing full resolution",
};

/** The phase in words; an unknown phase (a newer server) as it comes, underscores as spaces. */
export function phaseLabel(phase: string): string {
  return PHASES[phase] ?? phase.replace(/_/g, " ");
}

/** "Factorizing… building the coarse level 42% · 1.3 s": the percentage only inside a phase. */
export function progressText(prefix: string, p: ProgressLike): string {
  const inside = p.fraction > 0 && p.fraction < 1 ? ` ${Math.floor(p.fraction * 100)}%` : "";
  return `${prefix} ${phaseLabel(p.phase)}${inside} · ${p.elapsedSeconds.toFixed(1)} s`;
}

/** Reads a *WithProgress stream: calls onProgress for each progress event and returns the
 * response (the last event). Throws if the stream ends without one. */
export async function readWithProgress<R>(
  stream: AsyncIterable<ProgressEvent<R>>,
  onProgress: (p: ProgressLike) => void,
): Promise<R> {
  let response: R | undefined;
  for await (const e of stream) {
    if (e.event.case === "progress") onProgress(e.event.value);
    else if (e.event.case === "response") response = e.event.value;
  }
  if (response === undefined) throw new Error("the server's progress stream ended without a response");
  return response;
}
