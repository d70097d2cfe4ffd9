// End-to-end (issue 17, point 2): a reload restores every setting and the undo history, because
// the server keeps them with the session; view preferences (heat map, wireframe) stay in the
// browser. Env and run: see harness.mjs; node --test tests/viewer/
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

const controls = (page) => page.evaluate(() => ({
  method: document.querySelector('[data-testid="method"]').value,
  ora: document.querySelector('[data-testid="ora"]').checked,
  iterations: document.querySelector('[data-testid="iterations"]').value,
  rigidity: document.querySelector('[data-testid="rigidity"]').value,
  heatmap: document.querySelector('[data-testid="heatmap"]').checked,
  heatmapMode: document.querySelector('[data-testid="heatmap-mode"]').value,
  wireframe: document.querySelector('[data-testid="wireframe"]').checked,
  undo: !document.querySelector('[data-testid="undo"]').disabled,
  redo: !document.querySelector('[data-testid="redo"]').disabled,
}));

async function setSlider(page, step) {
  await page.locator('[data-testid="rigidity"]').evaluate((el, v) => {
    el.value = String(v);
    el.dispatchEvent(new Event("input", { bubbles: true }));
    el.dispatchEvent(new Event("change", { bubbles: true }));
  }, step);
}

async function dragHandle(page, dx, dy) {
  const rev = await hook(page, () => window.__meshdeform.revision);
  const handle = (await hook(page, () => window.__meshdeform.groups())).findIndex((g) => g.role === "handle");
  const p = await hook(page, (g) => window.__meshdeform.groupScreenPoint(g), handle);
  await drag(page, p, dx, dy);
  await poll(page, (r) => window.__meshdeform.revision > r, rev, "drag revision");
  await settle(page);
}

async function clickAndSettle(page, id) {
  const rev = await hook(page, () => window.__meshdeform.revision);
  await page.locator(`[data-testid="${id}"]`).click();
  await poll(page, (r) => window.__meshdeform.revision > r, rev, `${id} revision`);
  await settle(page);
}

const near = (a, b, tol = 1e-9) => a.length === b.length && a.every((x, i) => Math.abs(x - b[i]) <= tol);
const sameStates = (a, b) => a.length === b.length && a.every((s, i) =>
  near(s.translation, b[i].translation) && near(s.rotation, b[i].rotation) && Math.abs(s.scale - b[i].scale) <= 1e-9);

test("a reload restores every setting and the undo history", { timeout: 240_000 }, async (t) => {
  let page, before, statesAfterFirst, statesAfterSecond;

  await t.test("the editor changes settings, drags twice and undoes once", async () => {
    page = await newPage(env.browser, env.baseUrl);
    await poll(page, () => window.__meshdeform?.ready === true, null, "editor ready");
    // Each settings change is a step of its own (issue 44) once its solve is in: wait for it, so
    // that quick changes are not coalesced into one (as they may be on a busy machine).
    const settingStep = async (what, change) => {
      const rev = await hook(page, () => window.__meshdeform.revision);
      await change();
      await poll(page, (r) => window.__meshdeform.revision > r, rev, `${what}: its solve`);
      await settle(page, `${what}: settle`);
    };
    await settingStep("iterations", async () => {
      await page.locator('[data-testid="iterations"]').fill("5");
      await page.locator('[data-testid="iterations"]').dispatchEvent("change");
    });
    await settingStep("ora", () => page.locator('[data-testid="ora"]').check());
    await settingStep("rigidity", () => setSlider(page, 3));
    await page.locator('[data-testid="heatmap"]').check();
    await page.locator('[data-testid="heatmap-mode"]').selectOption("area");
    await page.locator('[data-testid="wireframe"]').check();
    await dragHandle(page, 30, -20);
    statesAfterFirst = await hook(page, () => window.__meshdeform.moveStates());
    await dragHandle(page, -25, -30);
    statesAfterSecond = await hook(page, () => window.__meshdeform.moveStates());
    assert.ok(!sameStates(statesAfterFirst, statesAfterSecond), "the second drag moved the handle");
    await clickAndSettle(page, "undo");
    assert.ok(sameStates(await hook(page, () => window.__meshdeform.moveStates()), statesAfterFirst), "undo went back one drag");
    before = await controls(page);
    assert.deepEqual(before, {
      method: "1", ora: true, iterations: "5", rigidity: "3", heatmap: true, heatmapMode: "area", wireframe: true, undo: true, redo: true,
    });
    assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
  });

  await t.test("the reloaded page shows the same settings, states, shape and history", async () => {
    const revision = await hook(page, () => window.__meshdeform.revision);
    const positions = await hook(page, () => window.__meshdeform.positions());
    await page.reload();
    await poll(page, (r) => window.__meshdeform?.ready === true && window.__meshdeform.revision >= r, revision, "reloaded at the revision");
    assert.deepEqual(await controls(page), before);
    const restored = await hook(page, () => window.__meshdeform.moveStates());
    assert.ok(sameStates(restored, statesAfterFirst), `the handle's move state is restored: ${JSON.stringify(restored)} vs ${JSON.stringify(statesAfterFirst)}`);
    assert.equal(await hook(page, () => window.__meshdeform.revision), revision, "the reload itself committed nothing");
    assert.ok(near(await hook(page, () => window.__meshdeform.positions()), positions, 1e-6), "same shape on screen");
    await shot(page, "settings-a-reloaded.png");
  });

  await t.test("redo and undo continue the restored history", async () => {
    await clickAndSettle(page, "redo");
    assert.ok(sameStates(await hook(page, () => window.__meshdeform.moveStates()), statesAfterSecond), "redo: the second drag");
    assert.equal((await controls(page)).redo, false);
    await clickAndSettle(page, "undo");
    await clickAndSettle(page, "undo");
    const states = await hook(page, () => window.__meshdeform.moveStates());
    assert.ok(states.every((s) => near(s.translation, [0, 0, 0]) && near(s.rotation, [1, 0, 0, 0]) && s.scale === 1), "back to the handles as set");
    // The settings changes before the drags are steps too (issue 44): undo walks back through
    // them to the session's first settings.
    assert.equal((await controls(page)).undo, true);
    for (let i = 0; i < 3; i++) await clickAndSettle(page, "undo");
    const first = await controls(page);
    assert.deepEqual({ method: first.method, ora: first.ora, iterations: first.iterations, rigidity: first.rigidity, undo: first.undo },
      { method: "1", ora: false, iterations: "2", rigidity: "6", undo: false });
    assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
  });

  await t.test("a method switch is kept too, without a drag", async () => {
    const rev = await hook(page, () => window.__meshdeform.revision);
    await page.locator('[data-testid="ora"]').uncheck();
    await page.locator('[data-testid="method"]').selectOption("3");
    await poll(page, (r) => window.__meshdeform.revision > r, rev, "re-solve with the Laplacian method");
    await settle(page);
    await page.reload();
    await poll(page, () => window.__meshdeform?.ready === true, null, "reloaded");
    const c = await controls(page);
    assert.equal(c.method, "3");
    assert.equal(c.ora, false);
    assert.equal(await page.locator('[data-testid="rigidity"]').isDisabled(), true, "no scale control for the Laplacian method");
    await page.close();
  });
});
