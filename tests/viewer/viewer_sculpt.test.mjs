// End-to-end (issue 44: the viewer as a sculptor would use it), in real headless Chromium against
// a real server: one subtest per failure the issue lists — stale digits in numeric entry, exact
// undo of drags / reset / a deletion, the fixed-group dead end, modal G with the pointer, pick and
// drag on an uploaded mesh with no groups, a fixed heat-map scale across updates — plus the
// opening view. Env and run: see harness.mjs; node --test tests/viewer/
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { mkdtempSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { bboxDiag, centroid, displacements, drag, hook, newPage, poll, settle, shot, startAll, withTimeout, STEP_MS } from "./harness.mjs";

let env;

before(async () => {
  env = await startAll();
});

after(async () => {
  await env?.stop();
});

const maxDiff = (a, b) => {
  assert.equal(a.length, b.length);
  let m = 0;
  for (let i = 0; i < a.length; i++) m = Math.max(m, Math.abs(a[i] - b[i]));
  return m;
};

/** A tube along z (rings x segments, open ends): an upload with no groups and a long axis. */
function tubeObj(rings = 24, segments = 16, length = 4, radius = 0.35) {
  const lines = [];
  for (let r = 0; r < rings; r++) {
    for (let s = 0; s < segments; s++) {
      const a = (2 * Math.PI * s) / segments;
      lines.push(`v ${(radius * Math.cos(a)).toFixed(6)} ${(radius * Math.sin(a)).toFixed(6)} ${((length * r) / (rings - 1)).toFixed(6)}`);
    }
  }
  for (let r = 0; r + 1 < rings; r++) {
    for (let s = 0; s < segments; s++) {
      const a = r * segments + s + 1, b = r * segments + ((s + 1) % segments) + 1;
      const c = a + segments, d = b + segments;
      lines.push(`f ${a} ${b} ${d}`, `f ${a} ${d} ${c}`);
    }
  }
  return lines.join("\n") + "\n";
}

test("sculpting in the viewer", { timeout: 280_000 }, async (t) => {
  let page, diag, rest;
  const positions = () => hook(page, () => window.__meshdeform.positions());
  const groups = () => hook(page, () => window.__meshdeform.groups());
  const revision = () => hook(page, () => window.__meshdeform.revision);
  const historyState = () => hook(page, () => window.__meshdeform.history());
  const handleIndex = async () => (await groups()).findIndex((g) => g.role === "handle");
  /** Waits for a revision after `rev`, then until refinement rests and the history step is done. */
  async function afterRevision(rev, what) {
    await poll(page, (r) => window.__meshdeform.revision > r, rev, what);
    await settle(page, `${what}: settle`);
    await poll(page, () => !window.__meshdeform.historyBusy, null, `${what}: history idle`);
  }
  async function undoRedo(redo, what) {
    const rev = await revision();
    await page.keyboard.press(redo ? "Control+Shift+z" : "Control+z");
    await afterRevision(rev, what);
  }
  async function dragGroup(i, dx, dy, what) {
    const rev = await revision();
    await drag(page, await hook(page, (g) => window.__meshdeform.groupScreenPoint(g), i), dx, dy);
    await afterRevision(rev, what);
  }

  await t.test("(a) the sample opens looking across its longest axis", async () => {
    page = await newPage(env.browser, `${env.baseUrl}/?lambda=1e6`);
    await poll(page, () => window.__meshdeform?.ready === true, null, "editor ready");
    rest = await hook(page, () => window.__meshdeform.restPositions());
    diag = bboxDiag(rest);
    const lo = [0, 1, 2].map((k) => Math.min(...rest.filter((_, i) => i % 3 === k)));
    const hi = [0, 1, 2].map((k) => Math.max(...rest.filter((_, i) => i % 3 === k)));
    const size = hi.map((x, k) => x - lo[k]);
    const longest = size.indexOf(Math.max(...size));
    const dir = await hook(page, () => window.__meshdeform.viewDirection());
    console.log(`bbox ${size.map((x) => x.toFixed(2))}, view ${dir.map((x) => x.toFixed(2))}`);
    assert.ok(Math.abs(dir[longest]) < 0.5, `the view is across axis ${longest}, not along it: ${dir}`);
    await page.keyboard.press("7");
    assert.ok((await hook(page, () => window.__meshdeform.viewDirection()))[1] < -0.99, "7: top view");
    await page.keyboard.press("1");
    assert.ok((await hook(page, () => window.__meshdeform.viewDirection()))[2] < -0.99, "1: front view");
    await page.locator('[data-testid="view-side"]').click();
    assert.ok((await hook(page, () => window.__meshdeform.viewDirection()))[0] < -0.99, "Side: from +x");
    await page.keyboard.press("f");
    await shot(page, "sculpt-a-home.png");
  });

  await t.test("(b) numeric entry: a new command never keeps the last one's digits", async () => {
    const h = await handleIndex();
    await page.locator(`[data-testid="group-item-${h}"]`).click();
    const before = await positions();
    let rev = await revision();
    // The issue: G 1 Enter (no axis) left the command open, and R Y 4 5 then showed "Rotate about
    // Y: 145°". The same keys with a move this mesh takes well (0.1 of its 2 units).
    for (const k of ["g", ".", "1", "Enter"]) await page.keyboard.press(k);
    assert.equal(await hook(page, () => window.__meshdeform.modal), "", "G .1 Enter closes the command");
    await afterRevision(rev, "G .1 Enter");
    let st = (await hook(page, () => window.__meshdeform.moveStates()))[h];
    assert.deepEqual(st.translation.map((x) => Number(x.toFixed(9))), [0.1, 0, 0], "no axis typed: along X");
    rev = await revision();
    for (const k of ["r", "y", "4", "5"]) await page.keyboard.press(k);
    assert.match(await hook(page, () => window.__meshdeform.modal), /^Rotate about Y: 45°/);
    await page.keyboard.press("Enter");
    await afterRevision(rev, "R Y 45");
    st = (await hook(page, () => window.__meshdeform.moveStates()))[h];
    const half = (45 * Math.PI) / 360;
    assert.ok(Math.abs(st.rotation[0] - Math.cos(half)) < 1e-9 && Math.abs(st.rotation[2] - Math.sin(half)) < 1e-9, `45° about Y: ${st.rotation}`);
    // G then R before Enter: the rotation starts with an empty number too.
    for (const k of ["g", "7", "r"]) await page.keyboard.press(k);
    assert.match(await hook(page, () => window.__meshdeform.modal), /^Rotate about the view axis: …/);
    await page.keyboard.press("Escape");
    await settle(page);
    await poll(page, () => !window.__meshdeform.historyBusy, null, "cancel done");
    // Both numeric steps undo exactly.
    await undoRedo(false, "undo the rotation");
    await undoRedo(false, "undo the move");
    assert.equal(maxDiff(await positions(), before), 0, "numeric steps undo exactly");
  });

  let p0, p1, p2;
  await t.test("(c) undo and redo of drags give the earlier shapes exactly", async () => {
    const h = await handleIndex();
    p0 = await positions();
    await dragGroup(h, 60, -30, "drag 1");
    p1 = await positions();
    await dragGroup(h, -50, -40, "drag 2");
    p2 = await positions();
    assert.ok(maxDiff(p1, p2) > 0.01 * diag, "the drags changed the shape");
    await undoRedo(false, "undo drag 2");
    assert.equal(maxDiff(await positions(), p1), 0, "undo: the first drag's shape, exactly");
    await undoRedo(false, "undo drag 1");
    assert.equal(maxDiff(await positions(), p0), 0, "undo: the shape before the drags, exactly");
    await undoRedo(true, "redo drag 1");
    assert.equal(maxDiff(await positions(), p1), 0, "redo: exactly");
    await undoRedo(true, "redo drag 2");
    assert.equal(maxDiff(await positions(), p2), 0, "redo: exactly");
  });

  await t.test("(d) reset, its undo and its redo are exact", async () => {
    const rev = await revision();
    await page.locator('[data-testid="reset-rest"]').click();
    await afterRevision(rev, "reset");
    assert.equal(maxDiff(await positions(), rest), 0, "reset: the rest mesh itself");
    await undoRedo(false, "undo reset");
    assert.equal(maxDiff(await positions(), p2), 0, "undo of the reset: exactly the shape before");
    await undoRedo(true, "redo reset");
    assert.equal(maxDiff(await positions(), rest), 0, "redo of the reset: exactly the rest");
    assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
  });

  await t.test("(e) a deletion is a step: undo brings the group back, and the drags before it undo exactly", async () => {
    // A second handle picked on the side of the tube (Grab), dragged.
    const before = await positions();
    const g0 = await groups();
    const fixedC = centroid(rest, g0.find((g) => g.role === "fixed").vertices);
    const handleC = centroid(rest, g0.find((g) => g.role === "handle").vertices);
    const mid = fixedC.map((x, k) => x + 0.55 * (handleC[k] - x));
    await page.locator('[data-testid="tool-grab"]').click();
    await page.locator('[data-testid="grab-radius"]').evaluate((el) => { el.value = "0.04"; el.dispatchEvent(new Event("input")); });
    let rev = await revision();
    const at = await hook(page, (q) => window.__meshdeform.worldScreenPoint(q[0], q[1], q[2]), mid);
    await drag(page, at, 40, 20);
    await afterRevision(rev, "pick and drag a second handle");
    await poll(page, () => window.__meshdeform.groups().length === 3, null, "the pick made a third group");
    const picked = await positions();
    assert.ok(maxDiff(picked, before) > 1e-3 * diag, "the pick dragged the surface");
    const g = await groups();
    const first = g.findIndex((x) => x.role === "handle");
    // Delete the first handle (the rest is valid: applied at once, the shape untouched).
    rev = await revision();
    await page.locator(`[data-testid="group-delete-${first}"]`).click();
    await poll(page, () => window.__meshdeform.groups().length === 2 && window.__meshdeform.ready, null, "deletion applied");
    assert.equal(maxDiff(await positions(), picked), 0, "deleting moves nothing");
    const afterDelete = await historyState();
    // Undoing a deletion needs no new revision (the shape is already right): wait for the groups.
    await page.keyboard.press("Control+z");
    await poll(page, () => window.__meshdeform.groups().length === 3 && !window.__meshdeform.historyBusy, null, "the group is back");
    assert.deepEqual((await groups()).map((x) => x.vertices), g.map((x) => x.vertices), "the same groups as before the deletion");
    assert.equal(maxDiff(await positions(), picked), 0, "and the same shape");
    assert.equal((await historyState()).position, afterDelete.position - 1);
    await undoRedo(false, "undo the pick's drag");
    assert.equal(maxDiff(await positions(), before), 0, "the drag before the deletion undoes exactly");
    await page.locator('[data-testid="tool-move"]').click();
    await shot(page, "sculpt-e-undone.png");
  });

  await t.test("(f) deleting the only fixed group: what to do, one click to do it, Ctrl+Z undoes it", async () => {
    // Back to two groups: undo the pick's group change.
    await page.keyboard.press("Control+z");
    await poll(page, () => window.__meshdeform.groups().length === 2 && !window.__meshdeform.historyBusy, null, "two groups");
    const g = await groups();
    const fixed = g.findIndex((x) => x.role === "fixed");
    await page.locator(`[data-testid="group-delete-${fixed}"]`).click();
    await poll(page, () => /No fixed region/.test(window.__meshdeform.notice()), null, "the notice says what is missing");
    assert.equal(await page.locator('[data-testid="notice-fix-far"]').isVisible(), true);
    assert.equal(await page.locator('[data-testid="notice-undo"]').isVisible(), true);
    assert.equal(await page.locator("#hint").isVisible(), false, "no hint telling to switch to Move while Move is on");
    assert.equal(await hook(page, () => window.__meshdeform.ready), false);
    assert.doesNotMatch(await hook(page, () => window.__meshdeform.notice()), /still applies|switch to Move/);
    await shot(page, "sculpt-f-dead-end.png");
    // Ctrl+Z undoes the deletion, not the last drag.
    const rev = await revision();
    await page.keyboard.press("Control+z");
    await poll(page, () => window.__meshdeform.draftGroups().length === 2 && window.__meshdeform.ready && !window.__meshdeform.historyBusy, null, "deletion undone");
    assert.equal(await revision(), rev, "undoing the deletion moved nothing");
    assert.equal(await hook(page, () => window.__meshdeform.notice()), "");
    assert.equal(await page.locator('[data-testid="state-notice"]').isVisible(), false, "no notice outlives its cause");
    // Again, and this time one click fixes it.
    await page.locator(`[data-testid="group-delete-${fixed}"]`).click();
    await poll(page, () => /No fixed region/.test(window.__meshdeform.notice()), null, "notice again");
    await page.locator('[data-testid="notice-fix-far"]').click();
    await poll(page, () => window.__meshdeform.ready && window.__meshdeform.groups().length === 2, null, "far side fixed and applied");
    const now = await groups();
    assert.deepEqual(now.map((x) => x.role).sort(), ["fixed", "handle"]);
    assert.equal(await hook(page, () => window.__meshdeform.notice()), "");
    await dragGroup(now.findIndex((x) => x.role === "handle"), 30, -20, "drag after the fix");
    // Clear: the notice says there is nothing to drag, and no error is left up.
    await page.locator('[data-testid="tool-brush"]').click();
    await page.locator("#clear-selection").click();
    await poll(page, () => /Nothing to drag yet/.test(window.__meshdeform.notice()), null, "nothing to drag");
    assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
    assert.equal(await page.locator('[data-testid="notice-pick"]').isVisible(), true);
    // And undo brings the groups back.
    await page.keyboard.press("Control+z");
    await poll(page, () => window.__meshdeform.draftGroups().length === 2 && window.__meshdeform.notice() === "", null, "clear undone");
    await page.locator('[data-testid="tool-move"]').click();
    await poll(page, () => window.__meshdeform.ready, null, "ready after clear undone");
  });

  await t.test("(g) G follows the pointer; a click confirms, a right-click cancels exactly", async () => {
    const h = await handleIndex();
    await page.locator(`[data-testid="group-item-${h}"]`).click();
    const start = await hook(page, (g) => window.__meshdeform.groupScreenPoint(g), h);
    await page.mouse.move(start.x + 10, start.y + 10);
    const before = await positions();
    const hist = await historyState();
    let rev = await revision();
    await page.keyboard.press("g");
    assert.match(await hook(page, () => window.__meshdeform.modal), /^Move \(follows the pointer/);
    await page.mouse.move(start.x + 70, start.y + 10, { steps: 8 });
    await poll(page, (r) => window.__meshdeform.revision > r, rev, "the group follows the pointer before any click");
    await page.mouse.down();
    await page.mouse.up();
    assert.equal(await hook(page, () => window.__meshdeform.modal), "", "a click confirms");
    await settle(page);
    const moved = await hook(page, (g) => window.__meshdeform.groupScreenPoint(g), h);
    console.log(`G: group centre on screen ${start.x.toFixed(0)},${start.y.toFixed(0)} -> ${moved.x.toFixed(0)},${moved.y.toFixed(0)}`);
    assert.ok(moved.x - start.x > 30 && Math.abs(moved.y - start.y) < 15, "the group went where the pointer went");
    assert.equal((await historyState()).position, hist.position + 1, "one step");
    // An axis lock: only x changes.
    const s0 = (await hook(page, () => window.__meshdeform.moveStates()))[h];
    rev = await revision();
    await page.keyboard.press("g");
    await page.keyboard.press("x");
    await page.mouse.move(moved.x + 40, moved.y + 40, { steps: 6 });
    await poll(page, (r) => window.__meshdeform.revision > r, rev, "axis-locked move");
    await page.keyboard.press("Enter");
    await settle(page);
    const s1 = (await hook(page, () => window.__meshdeform.moveStates()))[h];
    assert.ok(Math.abs(s1.translation[0] - s0.translation[0]) > 1e-3 * diag, "moved along X");
    assert.ok(Math.abs(s1.translation[1] - s0.translation[1]) < 1e-12 && Math.abs(s1.translation[2] - s0.translation[2]) < 1e-12, "only along X");
    // Cancel: everything exactly as before the command.
    const kept = await positions();
    rev = await revision();
    await page.keyboard.press("r");
    await page.mouse.move(moved.x - 40, moved.y + 60, { steps: 6 });
    await poll(page, (r) => window.__meshdeform.revision > r, rev, "rotation follows the pointer");
    await page.mouse.click(moved.x - 40, moved.y + 60, { button: "right" });
    assert.equal(await hook(page, () => window.__meshdeform.modal), "");
    await settle(page);
    await poll(page, () => !window.__meshdeform.historyBusy, null, "cancel done");
    assert.equal(maxDiff(await positions(), kept), 0, "a right-click cancels exactly");
    assert.ok(maxDiff(kept, before) > 0);
    await shot(page, "sculpt-g-modal.png");
  });

  await t.test("(h) the heat map keeps a fixed scale across updates and draws groups over it", async () => {
    await page.locator('[data-testid="heatmap"]').check();
    await page.locator('[data-testid="heatmap-mode"]').selectOption("angle");
    await page.locator('[data-testid="heat-scale"]').fill("2");
    await page.locator('[data-testid="heat-scale"]').dispatchEvent("change");
    const legend = await hook(page, () => window.__meshdeform.legend());
    assert.deepEqual(legend.slice(0, 3), ["0°", "1.0°", "≥ 2.0°"]);
    const h = await handleIndex();
    const g = await groups();
    const fixedV = g.find((x) => x.role === "fixed").vertices[0];
    for (const [dx, dy] of [[40, -20], [-30, 30], [20, 20]]) {
      await dragGroup(h, dx, dy, "drag with the heat map on");
      assert.deepEqual(await hook(page, () => window.__meshdeform.legend()), legend, "the legend did not rescale");
      const c = await hook(page, (v) => window.__meshdeform.vertexColor(v), fixedV);
      assert.deepEqual(c.map((x) => x.toFixed(2)), ["0.22", "0.42", "0.88"], "the fixed region keeps its colour over the map");
    }
    // Auto sets it once, on request.
    await page.locator('[data-testid="heat-auto"]').click();
    const auto = await hook(page, () => window.__meshdeform.legend());
    await dragGroup(h, -20, -20, "drag after Auto");
    assert.deepEqual(await hook(page, () => window.__meshdeform.legend()), auto, "Auto is not continuous");
    // A bad scale is refused where typed.
    await page.locator('[data-testid="heat-scale"]').fill("-1");
    await page.locator('[data-testid="heat-scale"]').dispatchEvent("change");
    assert.equal(await page.locator('[data-testid="heat-scale-note"]').isVisible(), true);
    assert.deepEqual(await hook(page, () => window.__meshdeform.legend()), auto);
    await shot(page, "sculpt-h-heat.png");
    await page.locator('[data-testid="heatmap"]').uncheck();
  });

  await t.test("(i) an uploaded mesh with no groups: press on it and drag", async () => {
    const dir = mkdtempSync(path.join(tmpdir(), "meshdeform-tube-"));
    const file = path.join(dir, "tube.obj");
    writeFileSync(file, tubeObj());
    const sid = await hook(page, () => window.__meshdeform.sessionId);
    await page.locator('[data-testid="upload-input"]').setInputFiles(file);
    await poll(page, (s) => window.__meshdeform.sessionId !== s && window.__meshdeform.revision >= 0, sid, "uploaded");
    assert.equal(await hook(page, () => window.__meshdeform.tool), "grab", "an upload without groups starts in Grab");
    assert.match(await hook(page, () => window.__meshdeform.notice()), /Nothing to drag yet: press on the mesh and drag/);
    const tubeRest = await hook(page, () => window.__meshdeform.restPositions());
    const tdiag = bboxDiag(tubeRest);
    // The wheel over the mesh sets the radius (and does not zoom).
    const v0 = 3 * 16 + 4; // a vertex near one end
    const at = await hook(page, (v) => window.__meshdeform.vertexScreenPoint(v), v0);
    await page.mouse.move(at.x, at.y);
    await poll(page, () => window.__meshdeform.hovering, null, "the radius preview is on the mesh");
    const r0 = Number(await page.locator('[data-testid="grab-radius"]').inputValue());
    const view0 = await hook(page, () => window.__meshdeform.viewDirection());
    await page.mouse.wheel(0, -300);
    await poll(page, (r) => Number(document.querySelector('[data-testid="grab-radius"]').value) > r, r0, "the wheel grew the radius");
    assert.deepEqual(await hook(page, () => window.__meshdeform.viewDirection()), view0);
    const rev = await revision();
    await drag(page, at, 0, -60);
    await poll(page, (r) => window.__meshdeform.revision > r && window.__meshdeform.groups().length >= 2, rev, "picked and dragged");
    await settle(page);
    const g = await groups();
    assert.deepEqual(g.map((x) => x.role), ["handle", "fixed"], "a handle around the point, the far side fixed");
    const p = await positions();
    const d = displacements(tubeRest, p);
    const handleMin = Math.min(...g[0].vertices.map((v) => d[v]));
    const fixedMax = Math.max(...g[1].vertices.map((v) => d[v]));
    console.log(`pick: handle ${g[0].vertices.length} v moved >= ${handleMin.toExponential(2)}, far side ${g[1].vertices.length} v moved <= ${fixedMax.toExponential(2)} (diag ${tdiag.toFixed(2)})`);
    assert.ok(handleMin > 0.02 * tdiag, "the picked region followed the pointer");
    assert.ok(fixedMax < 1e-4 * tdiag, "the far side stayed");
    assert.ok(g[0].vertices.includes(v0) || g[0].vertices.some((v) => Math.abs(tubeRest[v * 3 + 2] - tubeRest[v0 * 3 + 2]) < 0.5), "around the point");
    assert.equal(await hook(page, () => window.__meshdeform.notice()), "");
    assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
    await shot(page, "sculpt-i-picked.png");
    // One undo: the drag, exactly back to the rest shape; the next: the groups go.
    const revU = await revision();
    await page.keyboard.press("Control+z");
    await afterRevision(revU, "undo the pick's drag");
    assert.equal(maxDiff(await positions(), tubeRest), 0);
  });

  await withTimeout(page.close(), STEP_MS, "close");

  await t.test("(j) link-sized updates (issue 45) reach the page through the worker", async () => {
    // Lossless deltas: the page's positions must equal those of a page that loads the same
    // session's snapshot in doubles.
    const linked = await newPage(env.browser, `${env.baseUrl}/?updates=lossless`);
    try {
      await poll(linked, () => window.__meshdeform?.ready === true, null, "editor ready (lossless updates)");
      const handle = (await hook(linked, () => window.__meshdeform.groups())).findIndex((g) => g.role === "handle");
      const rev = await hook(linked, () => window.__meshdeform.revision);
      await drag(linked, await hook(linked, (g) => window.__meshdeform.groupScreenPoint(g), handle), 50, -30);
      await poll(linked, (r) => window.__meshdeform.revision > r, rev, "a drag's revision through delta updates");
      await settle(linked, "lossless: settle");
      const seen = await hook(linked, () => ({ revision: window.__meshdeform.revision, positions: window.__meshdeform.positions(), hash: location.hash }));
      const restL = await hook(linked, () => window.__meshdeform.restPositions());
      assert.ok(maxDiff(seen.positions, restL) > 1e-3 * bboxDiag(restL), "the drag moved the mesh on the page");
      assert.equal(await hook(linked, () => window.__meshdeform.lastError), "");
      const kinds = new Set(await hook(linked, () => window.__meshdeform.metrics().updateEncodings));
      assert.deepEqual([...kinds], ["lossless delta"], "every update was a lossless delta");
      // A second page on the same session, plain doubles: both show the same revision the same.
      const plain = await newPage(env.browser, `${env.baseUrl}/${seen.hash}`);
      try {
        await poll(plain, (r) => window.__meshdeform?.ready === true && window.__meshdeform.revision >= r, seen.revision, "the same session in doubles");
        let compared = false;
        for (let i = 0; i < 20 && !compared; i++) {
          const a = await hook(linked, () => ({ revision: window.__meshdeform.revision, positions: window.__meshdeform.positions() }));
          const b = await hook(plain, () => ({ revision: window.__meshdeform.revision, positions: window.__meshdeform.positions() }));
          if (a.revision !== b.revision) { await settle(linked, "lossless: settle again"); continue; }
          assert.equal(maxDiff(a.positions, b.positions), 0, `the deltas gave the same positions at revision ${a.revision}`);
          compared = true;
        }
        assert.ok(compared, "both pages showed one revision");
      } finally {
        await withTimeout(plain.close(), STEP_MS, "close");
      }
    } finally {
      await withTimeout(linked.close(), STEP_MS, "close");
    }
  });
});
