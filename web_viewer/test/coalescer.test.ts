import { describe, expect, it } from "vitest";
import { MoveCoalescer } from "../src/coalescer";

function deferred<T>() {
  let resolve!: (v: T) => void, reject!: (e: unknown) => void;
  const promise = new Promise<T>((a, b) => { resolve = a; reject = b; });
  return { promise, resolve, reject };
}

function setup() {
  const calls: { target: number; d: ReturnType<typeof deferred<string>> }[] = [];
  const results: string[] = [];
  const errors: unknown[] = [];
  const c = new MoveCoalescer<number, string>({
    send: (t) => { const d = deferred<string>(); calls.push({ target: t, d }); return d.promise; },
    key: (t) => String(t),
    onResult: (r) => results.push(r),
    onError: (e) => errors.push(e),
  });
  return { c, calls, results, errors };
}
const tick = () => new Promise((r) => setTimeout(r, 0));

describe("MoveCoalescer", () => {
  it("never drops a barrier: it goes after earlier targets and before later ones", async () => {
    const { c, calls } = setup();
    c.submit(1);
    c.submit(2);
    c.submit(7, false, true); // undo
    c.submit(3);
    c.submit(4);
    c.submit(8, false, true); // redo
    c.submit(5);
    const order = async () => {
      for (let i = 0; i < 10 && c.busy; i++) {
        calls[calls.length - 1].d.resolve("ok");
        await tick();
      }
    };
    await order();
    await c.idle();
    expect(calls.map((x) => x.target)).toEqual([1, 2, 7, 4, 8, 5]);
  });
  it("sends a barrier equal to the last target again", async () => {
    const { c, calls } = setup();
    c.submit(1);
    calls[0].d.resolve("r1");
    await c.idle();
    c.submit(1, false, true);
    expect(calls.map((x) => x.target)).toEqual([1, 1]);
    calls[1].d.resolve("r");
    await c.idle();
  });
  it("keeps one call in flight and sends only the newest target afterwards", async () => {
    const { c, calls, results } = setup();
    c.submit(1);
    c.submit(2);
    c.submit(3);
    c.submit(4);
    expect(calls.map((x) => x.target)).toEqual([1]);
    expect(c.busy).toBe(true);
    calls[0].d.resolve("r1");
    await tick();
    expect(calls.map((x) => x.target)).toEqual([1, 4]);
    calls[1].d.resolve("r4");
    await c.idle();
    expect(results).toEqual(["r1", "r4"]);
    expect(c.busy).toBe(false);
  });

  it("does not re-send an unchanged target", async () => {
    const { c, calls } = setup();
    c.submit(5);
    c.submit(5);
    calls[0].d.resolve("a");
    await tick();
    expect(calls.length).toBe(1);
    c.submit(5);
    expect(calls.length).toBe(1);
    c.submit(5, true);
    expect(calls.length).toBe(2);
  });

  it("drops a pending target equal to the one just sent", async () => {
    const { c, calls } = setup();
    c.submit(1);
    c.submit(2);
    c.submit(1);
    calls[0].d.resolve("a");
    await c.idle();
    expect(calls.map((x) => x.target)).toEqual([1]);
  });

  it("reports errors, continues with the pending target and allows a retry", async () => {
    const { c, calls, errors, results } = setup();
    c.submit(1);
    c.submit(2);
    calls[0].d.reject(new Error("boom"));
    await tick();
    expect(errors.length).toBe(1);
    expect(calls.map((x) => x.target)).toEqual([1, 2]);
    calls[1].d.reject(new Error("again"));
    await c.idle();
    expect(errors.length).toBe(2);
    c.submit(2); // failed target may be retried
    expect(calls.length).toBe(3);
    calls[2].d.resolve("ok");
    await c.idle();
    expect(results).toEqual(["ok"]);
  });

  it("handles a synchronous throw from send", async () => {
    const errors: unknown[] = [];
    const c = new MoveCoalescer<number, string>({
      send: () => { throw new Error("sync"); },
      key: String,
      onError: (e) => errors.push(e),
    });
    c.submit(1);
    await c.idle();
    expect(errors.length).toBe(1);
    expect(c.busy).toBe(false);
  });
});
