// Undo/redo of absolute move states. Undo re-sends the previous state as a new move (a new
// revision), so the stack only needs the states, not the geometry.

/** States kept, as the server keeps steps (server/service/edit_history.h kMaxHistorySteps). */
export const MAX_UNDO_STATES = 100;

export class UndoStack<T> {
  private states: T[];
  private index = 0;

  constructor(private readonly initial: T, private readonly limit = MAX_UNDO_STATES) {
    this.states = [initial];
  }

  /** Takes over a stored history (the server's): `states` oldest first, `index` the current. */
  restore(states: T[], index: number): void {
    if (states.length === 0) return this.reset();
    this.states = states.slice(-this.limit);
    const dropped = states.length - this.states.length;
    this.index = Math.min(Math.max(0, index - dropped), this.states.length - 1);
  }

  get current(): T {
    return this.states[this.index];
  }
  get canUndo(): boolean {
    return this.index > 0;
  }
  get canRedo(): boolean {
    return this.index < this.states.length - 1;
  }

  /** Records a committed state; drops the redo branch. Equal-to-current pushes are ignored. */
  push(state: T, equal: (a: T, b: T) => boolean = (a, b) => JSON.stringify(a) === JSON.stringify(b)): void {
    if (equal(state, this.current)) return;
    this.states.splice(this.index + 1);
    this.states.push(state);
    this.index++;
    while (this.states.length > this.limit) {
      this.states.shift();
      this.index--;
    }
  }

  undo(): T | null {
    if (!this.canUndo) return null;
    return this.states[--this.index];
  }

  redo(): T | null {
    if (!this.canRedo) return null;
    return this.states[++this.index];
  }

  /** New handles: old states refer to other groups and anchors. */
  reset(initial: T = this.initial): void {
    this.states = [initial];
    this.index = 0;
  }
}
