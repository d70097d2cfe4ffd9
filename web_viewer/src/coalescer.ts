// One MoveHandles in flight at a time, newest target wins: while a call is outstanding only the
// latest submitted target is kept; when the call settles the latest is sent if it differs from
// the one just sent. Keeps the server from queueing stale solves while the mouse moves fast.
// A target submitted as a barrier (undo, redo: the server's history must see each one) is never
// replaced: it is sent after whatever was submitted before it, and later targets wait for it.

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
  /** Barriers (and the targets submitted before them), in submission order. */
  private queue: T[] = [];
  private lastSentKey: string | null = null;
  private idleWaiters: (() => void)[] = [];
  sent = 0;

  constructor(private readonly opts: CoalescerOptions<T, R>) {}

  get busy(): boolean {
    return this.inFlight !== null;
  }

  /** Queue a target. `force` re-sends even if equal to the last sent (e.g. a method change);
   * a `barrier` is always sent, in order (see above). */
  submit(target: T, force = false, barrier = false): void {
    if (!force && !barrier && this.inFlight === null && this.opts.key(target) === this.lastSentKey) return;
    if (this.inFlight !== null && barrier) {
      if (this.pending !== null) this.queue.push(this.pending);
      this.pending = null;
      this.forcePending = false;
      this.queue.push(target);
      return;
    }
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
    this.queue = [];
    this.forcePending = false;
  }

  /** Resolves when nothing is in flight or pending. */
  idle(): Promise<void> {
    if (this.inFlight === null && this.pending === null && this.queue.length === 0) return Promise.resolve();
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
      const queued = this.queue.shift();
      if (queued !== undefined) {
        this.dispatch(queued);
        return;
      }
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
