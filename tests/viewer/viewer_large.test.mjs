// End-to-end (issue 44, point 6): on the 187,489-vertex plane the page keeps taking pointer input
// during a drag, drawing the coarse level of the multiresolution session while the button is
// down and the full mesh after the release. Updates are decoded and applied in a worker and at most one frame waits for the
// page, so every pointer event of the drag reaches the page's handler while frames arrive, and
// none of them waits for an update to be decoded. Conditions and counters only (no timings: the
// bench, bench/viewer_latency.mjs, measures the delays). Env and run: see harness.mjs.
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { hook, newPage, poll, settle, shot, startAll } from "./harness.mjs";

let env;

before(async () => {
  env = await startAll();
});

after(async () => {
  await env?.stop();
});

test("a 187k-vertex drag keeps taking pointer input", { timeout: 290_000 }, async () => {
  const page = await newPage(env.browser, `${env.baseUrl}/?sample=bumpy_plane_large`);
  // Creating the session and its multiresolution handles takes a while on a busy machine.
  await poll(page, () => window.__meshdeform?.ready === true, null, "large session ready", 200_000);
  assert.equal(await hook(page, () => window.__meshdeform.vertexCount), 187489);
  await settle(page, "refinement of nothing");
  // A coarse move outside a drag first (a scale-control change re-solves): its update brings the
  // coarse level's mesh, which the page must keep for the drags that follow.
  const revSlider = await hook(page, () => window.__meshdeform.revision);
  await page.locator('[data-testid="rigidity"]').evaluate((el) => {
    el.value = String(Number(el.value) - 1);
    el.dispatchEvent(new Event("input", { bubbles: true }));
    el.dispatchEvent(new Event("change", { bubbles: true }));
  });
  await poll(page, (r) => window.__meshdeform.revision > r, revSlider, "the re-solve of a scale-control change");
  await settle(page, "after the re-solve");
  assert.equal((await hook(page, () => window.__meshdeform.drawn())).coarse, false, "no coarse level outside a drag");
  // Every pointer event the browser delivers, counted before the page's own handlers (which stop
  // the event during a drag); coalesced events count as the events they stand for.
  await page.evaluate(() => {
    const w = window;
    w.__pointer = { events: 0, last: null, counting: false };
    window.addEventListener("pointermove", (e) => {
      if (!w.__pointer.counting) return;
      w.__pointer.events += e.getCoalescedEvents?.().length || 1;
      w.__pointer.last = [e.clientX, e.clientY];
    }, { capture: true });
  });
  const p = await hook(page, () => window.__meshdeform.handleScreenPoint());
  assert.ok(p, "a handle on screen");
  const rev0 = await hook(page, () => window.__meshdeform.revision);
  await page.mouse.move(p.x, p.y);
  await page.mouse.down();
  await page.evaluate(() => {
    window.__pointer.counting = true;
    window.__meshdeform.resetMetrics();
  });
  const moves = 40;
  let last = null;
  for (let i = 1; i <= moves; i++) {
    last = [Math.round(p.x + 2 * i), Math.round(p.y - 1.5 * i)];
    await page.mouse.move(last[0], last[1]);
  }
  // While the button is still down: the page has seen the drag's revisions, and draws the
  // coarse level they were solved on (a multiresolution session), not the 187k vertices.
  await poll(page, (r) => window.__meshdeform.revision > r, rev0, "a revision of the drag on screen while dragging");
  await poll(page, () => window.__meshdeform.drawn().coarse, null, "the coarse level drawn while dragging");
  const during = await hook(page, () => ({ pointer: { ...window.__pointer }, m: window.__meshdeform.metrics(), drawn: window.__meshdeform.drawn() }));
  assert.ok(during.drawn.vertices > 0 && during.drawn.vertices < 187489 / 4, `coarse level of ${during.drawn.vertices} vertices`);
  await shot(page, "large-drag-coarse.png");
  await page.mouse.up();
  await settle(page, "after the drag");
  // Released: the full mesh again, at once (whether or not a refinement revision came yet).
  assert.deepEqual(await hook(page, () => window.__meshdeform.drawn()), { coarse: false, vertices: 187489 });
  const m = await hook(page, () => window.__meshdeform.metrics());
  console.log(`187k drag: ${during.pointer.events} pointer events handled of ${moves}; ${m.inputDelayMs.length} drag handler runs, ` +
    `input delay p50 ${median(m.inputDelayMs).toFixed(1)} ms max ${Math.max(...m.inputDelayMs).toFixed(1)} ms; ` +
    `${m.updatesRendered} frames, ${m.updatesDropped} updates applied in the worker without a frame of their own, ` +
    `worker work p50 ${median(m.workerMs).toFixed(1)} ms`);
  assert.equal(during.pointer.events, moves, "every pointer event of the drag reached the page");
  assert.deepEqual(during.pointer.last, last, "the last position the page saw is the pointer's");
  assert.ok(during.m.inputDelayMs.length > 0, "the drag handler ran");
  assert.ok(during.m.updatesRendered > 0, "frames arrived during the drag");
  assert.ok(m.workerMs.length > 0 && m.workerMs.length === m.updatesRendered, "every frame was made in the worker");
  assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
  await shot(page, "large-drag.png");
  await page.close();
});

function median(a) {
  const s = [...a].sort((x, y) => x - y);
  return s.length ? s[Math.floor(s.length / 2)] : NaN;
}
