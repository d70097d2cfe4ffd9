// End-to-end (issue 17, point 1): after more edits than the server keeps revisions of, a late
// watcher and a reopened edit link show the same heat map as the editor, because the server
// always keeps revision 0 (the rest mesh) that the heat map compares against.
// Env and run: see harness.mjs; node --test tests/viewer/
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import { drag, hook, newPage, poll, settle, shot, startAll } from "./harness.mjs";

let env;

before(async () => {
  env = await startAll();
});

after(async () => {
  await env?.stop();
});

/** Turns the angle heat map on and returns what its legend says (the largest distortion). */
async function heatMapMax(page) {
  await page.locator('[data-testid="heatmap"]').check();
  await page.locator('[data-testid="heatmap-mode"]').selectOption("angle");
  return (await page.locator("#legend-max").textContent()).trim();
}

test("a late watcher and a reopened link show the editor's heat map", { timeout: 240_000 }, async (t) => {
  let editor, legend, revision;

  await t.test("the editor makes more edits than the server keeps", async () => {
    editor = await newPage(env.browser, env.baseUrl);
    await poll(editor, () => window.__meshdeform?.ready === true, null, "editor ready");
    const handle = (await hook(editor, () => window.__meshdeform.groups())).findIndex((g) => g.role === "handle");
    assert.ok(handle >= 0, "the demo has a handle group");
    // The server keeps revision 0 and the newest 4 (ServiceOptions::kept_revisions): 6 drags
    // push the first edits out.
    for (let i = 0; i < 6; i++) {
      const rev = await hook(editor, () => window.__meshdeform.revision);
      const p = await hook(editor, (g) => window.__meshdeform.groupScreenPoint(g), handle);
      await drag(editor, p, i % 2 === 0 ? 25 : -15, -20);
      await poll(editor, (r) => window.__meshdeform.revision > r, rev, `drag ${i + 1}`);
      await settle(editor, `drag ${i + 1}: settle`);
    }
    revision = await hook(editor, () => window.__meshdeform.revision);
    assert.ok(revision >= 6, `revision ${revision}`);
    legend = await heatMapMax(editor);
    assert.match(legend, /°$/);
    assert.notEqual(legend, "0.0°", "the edit distorts angles");
    await shot(editor, "reopen-a-editor.png");
  });

  await t.test("a watcher that opens the link now sees the same heat map", async () => {
    await editor.locator('[data-testid="share"]').click();
    const viewLink = await editor.locator('[data-testid="share-view-link"]').inputValue();
    const watcher = await newPage(env.browser, viewLink);
    await poll(watcher, (r) => window.__meshdeform?.revision >= r, revision, "watcher at the editor's revision");
    assert.match(viewLink, /#session=.+&token=.+/);
    assert.equal(await hook(watcher, () => window.__meshdeform.role), "view");
    assert.equal(await heatMapMax(watcher), legend);
    await shot(watcher, "reopen-b-late-watcher.png");
    await watcher.close();
  });

  await t.test("the edit link reopened (a reload) sees the same heat map", async () => {
    const editLink = await editor.locator('[data-testid="share-edit-link"]').inputValue();
    const reopened = await newPage(env.browser, editLink);
    await poll(reopened, (r) => window.__meshdeform?.ready === true && window.__meshdeform.revision >= r, revision,
      "reopened editor at the revision");
    assert.equal(await hook(reopened, () => window.__meshdeform.role), "edit");
    assert.equal(await heatMapMax(reopened), legend);
    await shot(reopened, "reopen-c-reopened.png");
    await reopened.close();
  });
});
