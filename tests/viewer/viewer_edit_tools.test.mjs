// End-to-end tests of the viewer's editing tools (issue 17) in real headless Chromium against a
// real server: broken links, several handle groups, reset to rest, numeric entry (G/R/S).
// Env and run: see harness.mjs; node --test tests/viewer/
import { test, before, after } from "node:test";
import assert from "node:assert/strict";
import {
  bboxDiag, centroid, closeSession, displacements, drag, hook, newPage, poll, serverSessions, settle, shot, startAll,
} from "./harness.mjs";

const NOTICE = "This link's session is gone or the link is incomplete";
let env;

before(async () => {
  env = await startAll();
});

after(async () => {
  await env?.stop();
});

/** The notice is up, nothing was created, the fragment is untouched and editing is off. */
async function assertLinkProblem(page, hash) {
  await poll(page, () => window.__meshdeform?.gone === true, null, "link problem reported");
  assert.equal(await page.locator('[data-testid="link-problem"]').isVisible(), true);
  assert.match(await page.locator('[data-testid="link-problem"]').textContent(), new RegExp(NOTICE));
  assert.equal(await page.locator('[data-testid="new-session"]').isVisible(), true);
  assert.equal(await page.evaluate(() => location.hash), hash, "the link is not rewritten");
  assert.equal(await hook(page, () => window.__meshdeform.sessionId), "");
  for (const id of ["tool-brush", "reset-rest", "apply-handles"]) {
    assert.equal(await page.locator(`[data-testid="${id}"]`).isDisabled(), true, `${id} disabled`);
  }
}

test("broken links are reported, not replaced", { timeout: 120_000 }, async (t) => {
  const base = env.baseUrl;
  const sessions0 = await serverSessions(base);

  await t.test("a session without a token", async () => {
    const page = await newPage(env.browser, `${base}/#session=abc`);
    await assertLinkProblem(page, "#session=abc");
    assert.match(await page.locator("#notice-text").textContent(), /no token/);
    await shot(page, "edit-a-no-token.png");
    await page.context().close();
  });

  await t.test("a session that does not exist (NOT_FOUND)", async () => {
    const page = await newPage(env.browser, `${base}/#session=nosuchsession&token=nosuchtoken`);
    await assertLinkProblem(page, "#session=nosuchsession&token=nosuchtoken");
    assert.match(await page.locator("#notice-text").textContent(), /no longer exists/);
    await page.context().close();
  });

  await t.test("no session was created by either link", async () => {
    assert.equal(await serverSessions(base), sessions0);
  });

  await t.test("the button offers a new session", async () => {
    const page = await newPage(env.browser, `${base}/#session=abc`);
    await assertLinkProblem(page, "#session=abc");
    await page.locator('[data-testid="new-session"]').click();
    await poll(page, () => window.__meshdeform?.ready === true, null, "new session ready");
    assert.match(await page.evaluate(() => location.hash), /^#session=[^&]+&token=./);
    assert.equal(await page.locator('[data-testid="link-problem"]').isVisible(), false);
    assert.equal(await serverSessions(base), sessions0 + 1);
    // The demo link shows the first-visit hint.
    assert.match(await page.locator('[data-testid="first-hint"]').textContent(), /orange handle/);
    await page.context().close();
  });
});

test("editing tools", { timeout: 240_000 }, async (t) => {
  let page, diag, rest;
  const positions = () => hook(page, () => window.__meshdeform.positions());
  const groups = () => hook(page, () => window.__meshdeform.groups());
  const handleIdx = async () => (await groups()).map((g, i) => (g.role === "handle" ? i : -1)).filter((i) => i >= 0);
  const revision = () => hook(page, () => window.__meshdeform.revision);
  async function afterRevision(rev, what) {
    await poll(page, (r) => window.__meshdeform.revision > r, rev, what);
    await settle(page, `${what}: settle`);
  }

  await t.test("(a) two separately painted patches become two more handle groups", async () => {
    // A stiff soft-handle weight, so handles sit on their targets to ~1e-6.
    page = await newPage(env.browser, `${env.baseUrl}/?lambda=1e6`);
    await poll(page, () => window.__meshdeform?.ready === true, null, "editor ready");
    rest = await hook(page, () => window.__meshdeform.restPositions());
    diag = bboxDiag(rest);
    const g0 = await groups();
    assert.equal(g0.length, 2);
    const fixedC = centroid(rest, g0.find((g) => g.role === "fixed").vertices);
    const handleC = centroid(rest, g0.find((g) => g.role === "handle").vertices);
    await page.locator('[data-testid="tool-brush"]').click();
    await page.locator('[data-testid="paint-mode"]').selectOption("handle");
    for (const f of [0.35, 0.65]) {
      // A point on the axis between the fixed region and the handle: the brush paints the
      // surface under it, well away from both.
      const a = fixedC.map((x, k) => x + f * (handleC[k] - x));
      const p = await hook(page, (q) => window.__meshdeform.worldScreenPoint(q[0], q[1], q[2]), a);
      await page.mouse.click(p.x, p.y);
    }
    assert.equal(await page.locator('[data-testid^="group-item-"]').count(), 4, "two strokes, two new groups");
    await page.locator('[data-testid="apply-handles"]').click();
    await poll(page, () => window.__meshdeform.groups().length === 4 && window.__meshdeform.ready, null, "4 groups applied");
    const g = await groups();
    assert.deepEqual(g.map((x) => x.role), ["fixed", "handle", "handle", "handle"]);
    const all = g.flatMap((x) => x.vertices);
    assert.equal(new Set(all).size, all.length, "no vertex in two groups");
    await shot(page, "edit-b-groups.png");
  });

  await t.test("(b) two handle groups move independently", async () => {
    const [, a, b] = await handleIdx();
    const g = await groups();
    const p0 = await positions();
    let rev = await revision();
    await drag(page, await hook(page, (i) => window.__meshdeform.groupScreenPoint(i), a), 70, -40);
    await afterRevision(rev, "drag group A");
    assert.equal(await hook(page, () => window.__meshdeform.selectedGroup), a, "grabbing a group selects it");
    const p1 = await positions();
    const d1 = displacements(p0, p1);
    const aMin = Math.min(...g[a].vertices.map((v) => d1[v]));
    const bMax = Math.max(...g[b].vertices.map((v) => d1[v]));
    console.log(`A moved >= ${aMin.toExponential(2)}, B moved <= ${bMax.toExponential(2)} (diag ${diag.toFixed(3)})`);
    assert.ok(aMin > 0.03 * diag, `group A moved (${aMin})`);
    assert.ok(bMax < 1e-4 * diag, `group B stayed (${bMax})`);

    rev = await revision();
    await drag(page, await hook(page, (i) => window.__meshdeform.groupScreenPoint(i), b), -60, 50);
    await afterRevision(rev, "drag group B");
    const p2 = await positions();
    const d2 = displacements(p1, p2);
    const bMin = Math.min(...g[b].vertices.map((v) => d2[v]));
    const aMax = Math.max(...g[a].vertices.map((v) => d2[v]));
    console.log(`B moved >= ${bMin.toExponential(2)}, A moved <= ${aMax.toExponential(2)}`);
    assert.ok(bMin > 0.03 * diag, `group B moved (${bMin})`);
    assert.ok(aMax < 1e-4 * diag, `group A kept its target (${aMax})`);
    await shot(page, "edit-c-two-moved.png");
  });

  await t.test("(b2) clicking a group on the mesh selects it", async () => {
    const fixed = (await groups())[0];
    assert.equal(fixed.role, "fixed");
    // Some of the group's vertices are hidden behind the mesh: try a bounded number of them.
    let selected = -1;
    for (let k = 0; k < 24 && selected !== 0; k++) {
      const v = fixed.vertices[(k * 47) % fixed.vertices.length];
      const p = await hook(page, (i) => window.__meshdeform.vertexScreenPoint(i), v);
      if (!p) continue;
      await page.mouse.click(p.x, p.y);
      selected = await hook(page, () => window.__meshdeform.selectedGroup);
    }
    assert.equal(selected, 0, "a click on the fixed region selected it");
    assert.match(await page.locator('[data-testid="group-item-0"]').getAttribute("class"), /\bsel\b/);
  });

  await t.test("(c) numeric entry: G X <number> Enter moves the selected group along X", async () => {
    const [, a, b] = await handleIdx();
    const g = await groups();
    await page.locator(`[data-testid="group-item-${a}"]`).click();
    assert.equal(await hook(page, () => window.__meshdeform.selectedGroup), a);
    const amount = Number((0.1 * diag).toFixed(3));
    const p0 = await positions();
    const rev = await revision();
    await page.keyboard.press("g");
    await page.keyboard.press("x");
    for (const ch of String(amount)) await page.keyboard.press(ch);
    assert.match(await page.locator('[data-testid="keycmd"]').textContent(), new RegExp(`^Move along X: ${amount} units`));
    await page.keyboard.press("Enter");
    assert.equal(await page.locator('[data-testid="keycmd"]').isVisible(), false);
    await afterRevision(rev, "numeric move");
    const p1 = await positions();
    const ca0 = centroid(p0, g[a].vertices), ca1 = centroid(p1, g[a].vertices);
    const moved = ca1.map((x, k) => x - ca0[k]);
    console.log(`typed ${amount}: group centroid moved by ${moved.map((x) => x.toExponential(3))}`);
    assert.ok(Math.abs(moved[0] - amount) < 1e-4 * diag, `x by ${amount}: ${moved[0]}`);
    assert.ok(Math.abs(moved[1]) < 1e-4 * diag && Math.abs(moved[2]) < 1e-4 * diag, `only x: ${moved}`);
    const d = displacements(p0, p1);
    for (const v of g[a].vertices) assert.ok(Math.abs(d[v] - amount) < 1e-3 * diag, `every vertex of the group moved by ${amount}`);
    assert.ok(Math.max(...g[b].vertices.map((v) => d[v])) < 1e-4 * diag, "the other group stayed");

    // Esc cancels: the typed amount was shown live, and the group goes back exactly.
    const kept = await positions();
    await page.keyboard.press("g");
    await page.keyboard.press("y");
    await page.keyboard.press("5");
    await page.keyboard.press("Escape");
    assert.equal(await page.locator('[data-testid="keycmd"]').isVisible(), false);
    await settle(page, "Esc: settle");
    await poll(page, () => !window.__meshdeform.historyBusy, null, "Esc: the cancel is done");
    const back = await positions();
    assert.equal(Math.max(...back.map((x, i) => Math.abs(x - kept[i]))), 0, "Esc puts the shape back exactly");
  });

  await t.test("(d) reset returns the rest pose exactly", async () => {
    const rev = await revision();
    await page.locator('[data-testid="reset-rest"]').click();
    await afterRevision(rev, "reset");
    const d = displacements(rest, await positions());
    const max = Math.max(...d);
    console.log(`after reset: max |p - rest| = ${max.toExponential(2)} (diag ${diag.toFixed(3)})`);
    assert.ok(max <= 1e-6 * diag, `rest pose within float rounding: ${max}`);
    await shot(page, "edit-d-reset.png");
  });

  await t.test("(e) reset also works after the groups were set on a deformed shape", async () => {
    const [, a, b] = await handleIdx();
    let rev = await revision();
    await drag(page, await hook(page, (i) => window.__meshdeform.groupScreenPoint(i), a), 50, 40);
    await afterRevision(rev, "drag before delete");
    // Deleting a group re-applies the others where they are now (deformed anchors).
    await page.locator(`[data-testid="group-delete-${b}"]`).click();
    await poll(page, () => window.__meshdeform.groups().length === 3 && window.__meshdeform.ready, null, "3 groups applied");
    const d0 = Math.max(...displacements(rest, await positions()));
    assert.ok(d0 > 0.03 * diag, "deformed before the reset");
    rev = await revision();
    await page.locator('[data-testid="reset-rest"]').click();
    await afterRevision(rev, "reset from deformed anchors");
    await poll(page, () => window.__meshdeform.ready, null, "ready after reset");
    const max = Math.max(...displacements(rest, await positions()));
    console.log(`after reset (deformed anchors): max |p - rest| = ${max.toExponential(2)}`);
    assert.ok(max <= 1e-6 * diag, `rest pose within float rounding: ${max}`);
    assert.equal(await hook(page, () => window.__meshdeform.lastError), "");
  });

  await t.test("(f) the iterations field refuses 0 and huge values where typed", async () => {
    const it = page.locator('[data-testid="iterations"]');
    await it.fill("0");
    assert.equal(await page.locator('[data-testid="iterations-note"]').isVisible(), true);
    assert.match(await page.locator('[data-testid="iterations-note"]').textContent(), /at least 1/);
    await it.fill("100000");
    assert.match(await page.locator('[data-testid="iterations-note"]').textContent(), /at most 1000/);
    await it.fill("3");
    assert.equal(await page.locator('[data-testid="iterations-note"]').isVisible(), false);
  });

  await t.test("(f2) wireframe and rest-pose ghost draw over the mesh", async () => {
    const rev = await revision();
    await drag(page, await hook(page, () => window.__meshdeform.handleScreenPoint()), 60, -30);
    await afterRevision(rev, "drag before the toggles");
    const canvas = page.locator('[data-testid="canvas"]');
    const frame = async () => { await page.waitForTimeout(300); return canvas.screenshot({ timeout: 30_000 }); };
    const plain = await frame();
    await page.locator('[data-testid="wireframe"]').check();
    const wire = await frame();
    assert.ok(!plain.equals(wire), "wireframe changes the picture");
    await page.locator('[data-testid="wireframe"]').uncheck();
    await page.locator('[data-testid="ghost-rest"]').check();
    const ghost = await frame();
    assert.ok(!plain.equals(ghost), "the rest ghost changes the picture");
    await shot(page, "edit-f2-ghost.png");
    await page.locator('[data-testid="ghost-rest"]').uncheck();
    assert.ok(plain.equals(await frame()), "both off: the same picture as before");
  });

  await t.test("(f3) ARAP is off while a magnify region exists", async () => {
    const arap = page.locator('[data-testid="method"] option[value="2"]');
    assert.equal(await arap.isDisabled(), false);
    await page.locator('[data-testid="tool-brush"]').click();
    const radius = (v) => page.locator('[data-testid="brush-radius"]').evaluate((el, x) => { el.value = String(x); el.dispatchEvent(new Event("input")); }, v);
    await page.locator('[data-testid="paint-mode"]').selectOption("magnify");
    await radius(0.02);
    const g = await groups();
    const mid = centroid(await positions(), [...g[0].vertices, ...g[1].vertices]);
    const p = await hook(page, (q) => window.__meshdeform.worldScreenPoint(q[0], q[1], q[2]), mid);
    await page.mouse.click(p.x, p.y);
    assert.equal(await arap.isDisabled(), true, "ARAP disabled");
    assert.match(await arap.getAttribute("title"), /Only the scale-aware method can magnify/);
    assert.equal(await page.locator('[data-testid="method-note"]').isVisible(), true);
    await page.locator('[data-testid="paint-mode"]').selectOption("erase");
    await radius(0.06); // a little wider: the re-solve after painting may have nudged the surface
    await page.mouse.click(p.x, p.y);
    assert.equal(await arap.isDisabled(), false, "ARAP back once the region is erased");
    assert.equal(await page.locator('[data-testid="method-note"]').isVisible(), false);
    assert.deepEqual(await groups(), g, "the groups are untouched");
    await page.locator('[data-testid="tool-move"]').click();
    await poll(page, () => window.__meshdeform.ready, null, "ready after the magnify round trip");
  });

  await t.test("(g) a closed session disables editing and says so", async () => {
    const hash = await page.evaluate(() => location.hash);
    const q = new URLSearchParams(hash.slice(1));
    assert.equal(await closeSession(env.baseUrl, q.get("session"), q.get("token")), 0);
    await poll(page, () => window.__meshdeform.gone === true, null, "gone after close");
    assert.match(await page.locator('[data-testid="link-problem"]').textContent(), new RegExp(NOTICE));
    for (const id of ["tool-brush", "reset-rest", "apply-handles", "method"]) {
      assert.equal(await page.locator(`[data-testid="${id}"]`).isDisabled(), true, `${id} disabled`);
    }
    assert.equal(await hook(page, () => window.__meshdeform.ready), false);
    await shot(page, "edit-g-closed.png");
  });
});
