// The scale-control slider (issue 12): the server's `rigidity` spans 0 (the paper's pure,
// scale-invariant method) to ARAP-like area preservation over several decades, so the slider
// moves over a log-spaced list of values instead of a linear range.

/** The values the slider can take, ascending; index 0 is the paper's pure method. */
export const RIGIDITY_STEPS: readonly number[] = [0, 0.1, 0.3, 1, 3, 10, 30, 100, 1000];

/** The slider index whose value is nearest to `value` (in log terms; 0 only for <= 0). */
export function rigidityStep(value: number): number {
  if (!Number.isFinite(value) || value <= 0) return 0;
  let best = 1;
  for (let i = 1; i < RIGIDITY_STEPS.length; i++) {
    if (Math.abs(Math.log(RIGIDITY_STEPS[i] / value)) < Math.abs(Math.log(RIGIDITY_STEPS[best] / value))) best = i;
  }
  return best;
}

/** The value of slider index `step` (clamped to the list). */
export function rigidityValue(step: number): number {
  const i = Math.min(RIGIDITY_STEPS.length - 1, Math.max(0, Math.round(Number.isFinite(step) ? step : 0)));
  return RIGIDITY_STEPS[i];
}

/** What the slider shows next to itself. */
export function rigidityLabel(value: number): string {
  return value === 0 ? "0 (paper: scale free)" : String(value);
}
