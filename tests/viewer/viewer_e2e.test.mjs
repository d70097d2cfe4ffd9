// End-to-end test of the browser viewer in real headless Chromium against a real server.
// Env: MESHDEFORM_SERVER_PATH (server binary), MESHDEFORM_VIEWER_DIST (built viewer, default
// web_viewer/dist), MESHDEFORM_ARTIFACTS_DIR (screenshots), CHROMIUM_PATH (default
// /usr/bin/chromium); the server and browser start in harness.mjs. Run: node --test tests/viewer/
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { mkdtempSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { artifacts, bboxDiag, hook, newPage as openPage, poll, settle, startAll, STEP_MS, withTimeout } from "./harness.mjs";

let env;
const newPage = (url) => openPage(env.browser, url);
let baseUrl;

async function shot(page, name) {
  return page.locator('[data-testid="canvas"]').screenshot({ path: path.join(artifacts, name), timeout: STEP_MS });
}

/** Drags the real mouse from the handle centroid by (dx, dy) pixels; returns the start point. */
async function dragHandle(page, dx, dy) {
  const p = await hook(page, () => window.__meshdeform.handleScreenPoint());
  assert.ok(p, "handleScreenPoint() is null");
  await page.mouse.move(p.x, p.y);
  await page.mouse.down();
  await page.mouse.move(p.x + dx, p.y + dy, { steps: 12 });
  await page.mouse.up();
  return p;
}

before(async () => {
  env = await startAll();
  baseUrl = env.baseUrl;
});

after(async () => {
  await env?.stop();
  console.log(`screenshots in ${artifacts}`);
});

test("viewer end to end", { timeout: 120_000 }, async (t) => {
  let editor, watcher;
  await t.test("(a) loads the default sample ready to drag", async () => {
    // A stiff soft-handle weight so that the fixed region stays put within 1e-6 (the server's
    // default lambda of 100 lets it drift by ~1e-4).
    editor = await newPage(`${baseUrl}/?lambda=1e6`);
    await poll(editor, () => window.__meshdeform?.ready === true, null, "editor ready");
    const h = await hook(editor, () => ({ ...window.__meshdeform }));
    assert.equal(h.role, "edit");
    assert.equal(h.vertexCount, 4802);
    assert.equal(h.lastError, "");
    assert.match(await editor.evaluate(() => location.hash), /^#session=[^&]+&token=/);
    await shot(editor, "a-loaded.png");
  });

  await t.test("(b) a real mouse drag moves the handle and keeps the fixed region", async () => {
    // Let background refinement settle so the comparison sees only the drag.
    await editor.waitForTimeout(500);
    const before = await hook(editor, () => window.__meshdeform.positions());
    const rev0 = await hook(editor, () => window.__meshdeform.revision);
    const img0 = await shot(editor, "b-before.png");
    await dragHandle(editor, 80, -40);
    await poll(editor, (r) => window.__meshdeform.revision > r, rev0, "revision after drag");
    await editor.waitForTimeout(800);
    const after = await hook(editor, () => window.__meshdeform.positions());
    let maxMove = 0;
    const moved = [];
    for (let i = 0; i < before.length / 3; i++) {
      const d = Math.hypot(after[i * 3] - before[i * 3], after[i * 3 + 1] - before[i * 3 + 1], after[i * 3 + 2] - before[i * 3 + 2]);
      moved.push(d);
      maxMove = Math.max(maxMove, d);
    }
    // Bounding-box diagonal of the rest mesh for a scale-free margin.
    const diag = bboxDiag(before);
    assert.ok(maxMove > 0.05 * diag, `handle moved ${maxMove} (diag ${diag})`);
    const groups = await hook(editor, () => window.__meshdeform.groups());
    const fixed = groups.find((g) => g.role === "fixed").vertices;
    const handle = groups.find((g) => g.role === "handle").vertices;
    assert.ok(fixed.length > 0 && handle.length > 0);
    const fixedMax = Math.max(...fixed.map((i) => moved[i]));
    assert.ok(fixedMax <= 1e-6, `fixed region moved by ${fixedMax}`);
    const handleMin = Math.min(...handle.map((i) => moved[i]));
    assert.ok(handleMin > 0.05 * diag, `every handle vertex moved clearly (min ${handleMin}, diag ${diag})`);
    const etheta = await editor.locator('[data-testid="metric-etheta"]').textContent();
    assert.ok(Number.isFinite(Number(etheta)), `E_theta shows a number: ${etheta}`);
    const img1 = await shot(editor, "b-after.png");
    assert.ok(!img0.equals(img1), "canvas pixels changed");
    const m = await hook(editor, () => window.__meshdeform.metrics());
    assert.ok(m.updatesRendered > 0 && m.updateBytes.length > 0);
    assert.ok(m.dragToFrameMs.length > 0, "dragToFrameMs recorded");
    console.log(`drag: max move ${maxMove.toFixed(3)}, dragToFrameMs median ${median(m.dragToFrameMs).toFixed(1)} ms over ${m.dragToFrameMs.length}, encodings ${[...new Set(m.updateEncodings)]}`);
  });

  await t.test("(c) the watch link follows the editor read-only", async () => {
    await editor.locator('[data-testid="share"]').click();
    const viewLink = await editor.locator('[data-testid="share-view-link"]').inputValue();
    const editLink = await editor.locator('[data-testid="share-edit-link"]').inputValue();
    assert.match(viewLink, /#session=.+&token=.+/);
    assert.notEqual(viewLink, editLink);
    watcher = await newPage(viewLink);
    await poll(watcher, () => window.__meshdeform?.revision >= 0, null, "watcher snapshot");
    assert.equal(await hook(watcher, () => window.__meshdeform.role), "view");
    assert.match(await watcher.locator('[data-testid="role"]').textContent(), /Watching \(read-only\)/);
    assert.equal(await watcher.locator('[data-testid="tool-brush"]').isDisabled(), true);
    // Same revision as the editor (refinement may still be committing: compare to the editor's latest).
    await withTimeout((async () => {
      for (;;) {
        const [a, b] = [await hook(editor, () => window.__meshdeform.revision), await hook(watcher, () => window.__meshdeform.revision)];
        if (a === b) return;
        await watcher.waitForTimeout(150);
      }
    })(), STEP_MS, "watcher reaches editor revision");
    const rev = await hook(editor, () => window.__meshdeform.revision);
    await dragHandle(editor, -60, 30);
    await poll(editor, (r) => window.__meshdeform.revision > r, rev, "editor new revision");
    const target = await hook(editor, () => window.__meshdeform.revision);
    await poll(watcher, (r) => window.__meshdeform.revision >= r, target, "watcher follows");
    await shot(watcher, "c-watcher.png");
  });

  await t.test("(d) a bad upload shows the server's error and keeps the session", async () => {
    const dir = mkdtempSync(path.join(tmpdir(), "meshdeform-upload-"));
    const bad = path.join(dir, "garbage.obj");
    writeFileSync(bad, "this is not a mesh\n\u0001\u0002 42 foo bar\nf 9 9 9\n");
    const before = await hook(editor, () => ({ sid: window.__meshdeform.sessionId, rev: window.__meshdeform.revision }));
    await editor.locator('[data-testid="upload-input"]').setInputFiles(bad);
    await poll(editor, () => window.__meshdeform.lastError !== "", null, "upload error");
    // Plain words first, the gRPC code and the server's message in small print.
    assert.match(await editor.locator("#error-text").textContent(), /^Upload failed: The file could not be read as a mesh\.$/);
    assert.match(await editor.locator('[data-testid="error-detail"]').textContent(), /^INVALID_ARGUMENT: ./);
    // The status line no longer says "Uploading …".
    assert.doesNotMatch(await editor.locator('[data-testid="status"]').textContent(), /Uploading/);
    const now = await hook(editor, () => ({ sid: window.__meshdeform.sessionId, rev: window.__meshdeform.revision, ready: window.__meshdeform.ready }));
    assert.equal(now.sid, before.sid);
    assert.ok(now.rev >= before.rev);
    assert.equal(now.ready, true);
    await shot(editor, "d-bad-upload.png");
  });

  await t.test("(d2) the scale-control slider re-solves live; the area heat map shows scale", async () => {
    await editor.locator("#error-close").click();
    assert.equal(await editor.locator('[data-testid="rigidity"]').isDisabled(), false);
    // Settles (bounded: no new revision for a while), then reads the area.
    const settledArea = async () => {
      await settle(editor);
      return Number(await editor.locator("#metric-area").textContent());
    };
    const setStep = async (step) => {
      const rev = await hook(editor, () => window.__meshdeform.revision);
      await editor.locator('[data-testid="rigidity"]').evaluate((el, v) => {
        el.value = String(v);
        el.dispatchEvent(new Event("input", { bubbles: true }));
        el.dispatchEvent(new Event("change", { bubbles: true }));
      }, step);
      await poll(editor, (r) => window.__meshdeform.revision > r, rev, `re-solve at slider step ${step}`);
    };
    await setStep(0);
    assert.match(await editor.locator('[data-testid="rigidity-val"]').textContent(), /^0/);
    const pure = await settledArea();
    await setStep(8);
    assert.equal(await editor.locator('[data-testid="rigidity-val"]').textContent(), "1000");
    const rigid = await settledArea();
    assert.ok(Number.isFinite(pure) && Number.isFinite(rigid), `areas ${pure} ${rigid}`);
    assert.ok(rigid < pure, `area log RMS with scale control ${rigid} < without ${pure}`);
    await editor.locator('[data-testid="heatmap"]').check();
    await editor.locator('[data-testid="heatmap-mode"]').selectOption("area");
    assert.match(await editor.locator("#legend-what").textContent(), /area/);
    await shot(editor, "d2-area-heatmap.png");
    await editor.locator('[data-testid="heatmap"]').uncheck();
    assert.equal(await hook(editor, () => window.__meshdeform.lastError), "");
  });

  await t.test("(e) switching to ARAP still drags", async () => {
    assert.equal(await hook(editor, () => window.__meshdeform.lastError), "");
    await editor.locator('[data-testid="method"]').selectOption("2");
    await editor.waitForTimeout(300);
    const rev = await hook(editor, () => window.__meshdeform.revision);
    await dragHandle(editor, 40, 40);
    await poll(editor, (r) => window.__meshdeform.revision > r, rev, "ARAP revision");
    assert.equal(await hook(editor, () => window.__meshdeform.lastError), "");
    await shot(editor, "e-arap.png");
  });
});

function median(a) {
  const s = [...a].sort((x, y) => x - y);
  return s.length ? s[Math.floor(s.length / 2)] : NaN;
}
