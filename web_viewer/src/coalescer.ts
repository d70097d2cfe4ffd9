// One MoveHandles in flight at a time, newest target wins: while a call is outstanding only the
// latest submitted target is kept; when the call settles the latest is sent if it differs from
// the one just sent. Keeps the server from queueing stale solves while the mouse moves fast.

export interface CoalescerOptions<T, R> {
  send: (target: T) => Promise<R>;
  /** Stable key of a target; equal keys are not re-sent. */
  key: (target: T) => string;
  onResult?: (result: R, target: T) => void;
  onError?: (err: unknown, target: T) => void;
}

export class MoveCoalescer<T, R> {
  private inFlight: T | null = null;
  private pending: T | null = null;
  private lastSentKey: string | null = null;
  private idleWaiters: (() => void)[] = [];
  sent = 0;

  constructor(private readonly opts: CoalescerOptions<T, R>) {}

  get busy(): boolean {
    return this.inFlight !== null;
  }

  /** Queue a target. `force` re-sends even if equal to the last sent (e.g. a method change). */
  submit(target: T, force = false): void {
    if (!force && this.inFlight === null && this.opts.key(target) === this.lastSentKey) return;
    if (this.inFlight !== null) {
      this.pending = target;
      this.forcePending = this.forcePending || force;
      return;
    }
    this.dispatch(target);
  }

  private forcePending = false;

  /** Forget the last sent target (after SetHandles the same target means a new solve). */
  reset(): void {
    this.lastSentKey = null;
    this.pending = null;
    this.forcePending = false;
  }

  /** Resolves when nothing is in flight or pending. */
  idle(): Promise<void> {
    if (this.inFlight === null && this.pending === null) return Promise.resolve();
    return new Promise((r) => this.idleWaiters.push(r));
  }

  private dispatch(target: T): void {
    this.inFlight = target;
    this.lastSentKey = this.opts.key(target);
    this.sent++;
    let p: Promise<R>;
    try {
      p = this.opts.send(target);
    } catch (e) {
      p = Promise.reject(e);
    }
    p.then(
      (r) => this.opts.onResult?.(r, target),
      (e) => {
        // A failed move did not commit: allow the same target to be tried again later.
        this.lastSentKey = null;
        this.opts.onError?.(e, target);
      },
    ).finally(() => {
      this.inFlight = null;
      const next = this.pending;
      const force = this.forcePending;
      this.pending = null;
      this.forcePending = false;
      if (next !== null && (force || this.opts.key(next) !== this.lastSentKey)) {
        this.dispatch(next);
      } else {
        const w = this.idleWaiters;
        this.idleWaiters = [];
        w.forEach((f) => f());
      }
    });
  }
}
