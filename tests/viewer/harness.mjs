// Shared by the viewer end-to-end tests: starts the real server (loopback, ephemeral ports, dies
// with the test process) and headless Chromium, opens pages with the test hooks, and speaks a
// little gRPC-Web to the server for checks the page cannot make (session counts, closing).
// Env: MESHDEFORM_SERVER_PATH, MESHDEFORM_VIEWER_DIST, MESHDEFORM_ARTIFACTS_DIR, CHROMIUM_PATH.
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { createRequire } from "node:module";
import { existsSync, mkdirSync, mkdtempSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";
import { fileURLToPath } from "node:url";

const require = createRequire(new URL("../../web_viewer/package.json", import.meta.url));
const { chromium } = require("playwright-core");

const repo = path.resolve(path.dirname(fileURLToPath(import.meta.url)), "../..");
export const serverPath = process.env.MESHDEFORM_SERVER_PATH || path.join(repo, "build/server/transport/meshdeform-server");
export const dist = path.resolve(process.env.MESHDEFORM_VIEWER_DIST || path.join(repo, "web_viewer/dist"));
export const artifacts = process.env.MESHDEFORM_ARTIFACTS_DIR || mkdtempSync(path.join(tmpdir(), "meshdeform-viewer-e2e-"));
mkdirSync(artifacts, { recursive: true });

export const STEP_MS = 30_000;

export function withTimeout(p, ms, what) {
  let t;
  return Promise.race([p, new Promise((_, rej) => (t = setTimeout(() => rej(new Error(`timeout: ${what}`)), ms)))]).finally(() => clearTimeout(t));
}

/** Starts the server and Chromium; returns { baseUrl, browser, stop() }. */
export async function startAll() {
  assert.ok(existsSync(serverPath), `server binary not found: ${serverPath}`);
  assert.ok(existsSync(path.join(dist, "index.html")), `viewer not built: ${dist}/index.html (run npm run build in web_viewer)`);
  let serverLog = "";
  const args = ["--listen", "127.0.0.1:0", "--http-listen", "127.0.0.1:0", "--web-root", dist, "--log-level", "info"];
  // The server dies with this test process however it ends (util-linux setpriv sets
  // PR_SET_PDEATHSIG before exec), and never holds the test's stdout.
  const server = existsSync("/usr/bin/setpriv")
    ? spawn("/usr/bin/setpriv", ["--pdeathsig", "KILL", serverPath, ...args], { stdio: ["ignore", "ignore", "pipe"] })
    : spawn(serverPath, args, { stdio: ["ignore", "ignore", "pipe"] });
  const baseUrl = await new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error("server did not report http_listening\n" + serverLog)), 20_000);
    server.on("error", (e) => { clearTimeout(timer); reject(e); });
    server.on("exit", (code) => { clearTimeout(timer); reject(new Error(`server exited (${code})\n${serverLog}`)); });
    let buf = "";
    server.stderr.on("data", (d) => {
      serverLog += d;
      buf += d;
      let i;
      while ((i = buf.indexOf("\n")) >= 0) {
        const line = buf.slice(0, i);
        buf = buf.slice(i + 1);
        try {
          const j = JSON.parse(line);
          if (j.event === "http_listening") { clearTimeout(timer); resolve(`http://127.0.0.1:${j.port}`); }
        } catch { /* not JSON */ }
      }
    });
  });
  const browser = await withTimeout(chromium.launch({
    executablePath: process.env.CHROMIUM_PATH || "/usr/bin/chromium",
    args: ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
      "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
    timeout: STEP_MS,
  }), STEP_MS + 5000, "chromium launch");
  async function stop() {
    try { await browser.close(); } catch { /* already gone */ }
    if (server.exitCode === null) {
      server.removeAllListeners("exit");
      server.kill("SIGTERM");
      await new Promise((r) => { const t = setTimeout(() => { server.kill("SIGKILL"); r(); }, 5000); server.once("exit", () => { clearTimeout(t); r(); }); });
    }
  }
  return { baseUrl, browser, stop };
}

export async function newPage(browser, url) {
  const ctx = await browser.newContext({ viewport: { width: 1200, height: 800 } });
  const page = await ctx.newPage();
  page.setDefaultTimeout(STEP_MS);
  page.on("pageerror", (e) => console.log("[pageerror]", e.message));
  page.on("console", (m) => { if (m.type() === "error" || m.type() === "warning") console.log(`[console.${m.type()}]`, m.text()); });
  await page.goto(url, { timeout: STEP_MS });
  return page;
}

export const hook = (page, expr, arg) => page.evaluate(expr, arg);

export async function poll(page, fn, arg, what, ms = STEP_MS) {
  await withTimeout(page.waitForFunction(fn, arg, { timeout: ms, polling: 100 }), ms + 1000, what);
}

/** Waits (bounded) until no new revision arrived for a while: refinement has settled. */
export async function settle(page, what = "revisions settle") {
  await withTimeout((async () => {
    let last = -1, same = 0;
    while (same < 6) {
      const r = await hook(page, () => window.__meshdeform.revision);
      same = r === last ? same + 1 : 0;
      last = r;
      await page.waitForTimeout(250);
    }
  })(), STEP_MS, what);
}

export async function shot(page, name) {
  return page.screenshot({ path: path.join(artifacts, name), timeout: STEP_MS });
}

/** Drags the real mouse from (x, y) by (dx, dy) pixels. */
export async function drag(page, p, dx, dy) {
  assert.ok(p, "no start point");
  await page.mouse.move(p.x, p.y);
  await page.mouse.down();
  await page.mouse.move(p.x + dx, p.y + dy, { steps: 12 });
  await page.mouse.up();
}

// ---- minimal gRPC-Web (binary) for the checks the page cannot make ----

function varint(n) {
  const out = [];
  do { let b = n & 0x7f; n = Math.floor(n / 128); if (n > 0) b |= 0x80; out.push(b); } while (n > 0);
  return out;
}
function stringField(tag, s) {
  const b = Buffer.from(s, "utf8");
  return [(tag << 3) | 2, ...varint(b.length), ...b];
}

async function unary(baseUrl, method, body) {
  const frame = Buffer.concat([Buffer.from([0, ...[24, 16, 8, 0].map((s) => (body.length >>> s) & 0xff)]), Buffer.from(body)]);
  const res = await fetch(`${baseUrl}/meshdeform.v1.DeformationService/${method}`, {
    method: "POST",
    headers: { "content-type": "application/grpc-web+proto", "x-grpc-web": "1" },
    body: frame,
    signal: AbortSignal.timeout(STEP_MS),
  });
  const buf = Buffer.from(await res.arrayBuffer());
  let msg = null, trailers = "";
  for (let o = 0; o + 5 <= buf.length;) {
    const flag = buf[o], len = buf.readUInt32BE(o + 1);
    const part = buf.subarray(o + 5, o + 5 + len);
    if (flag & 0x80) trailers += part.toString("utf8"); else msg = part;
    o += 5 + len;
  }
  const status = Number((/grpc-status:\s*(\d+)/i.exec(trailers + (res.headers.get("grpc-status") ? `grpc-status:${res.headers.get("grpc-status")}` : "")) ?? [])[1] ?? 0);
  return { status, msg: msg ?? Buffer.alloc(0) };
}

/** GetServerStats().sessions: how many sessions the server holds. */
export async function serverSessions(baseUrl) {
  const { status, msg } = await unary(baseUrl, "GetServerStats", []);
  assert.equal(status, 0, "GetServerStats failed");
  // Field 1 (varint); absent means 0.
  for (let o = 0; o < msg.length;) {
    const tag = msg[o++];
    if (tag === 0x08) {
      let v = 0, m = 1, b;
      do { b = msg[o++]; v += (b & 0x7f) * m; m *= 128; } while (b & 0x80);
      return v;
    }
    const wire = tag & 7;
    if (wire === 0) { while (msg[o++] & 0x80); }
    else if (wire === 1) o += 8;
    else if (wire === 5) o += 4;
    else if (wire === 2) { let l = 0, m = 1, b; do { b = msg[o++]; l += (b & 0x7f) * m; m *= 128; } while (b & 0x80); o += l; }
    else throw new Error(`unexpected wire type ${wire}`);
  }
  return 0;
}

/** CloseSession(session, edit token); returns the gRPC status code. */
export async function closeSession(baseUrl, sessionId, token) {
  const { status } = await unary(baseUrl, "CloseSession", [...stringField(1, sessionId), ...stringField(2, token)]);
  return status;
}

export function bboxDiag(p) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < p.length; i++) { lo[i % 3] = Math.min(lo[i % 3], p[i]); hi[i % 3] = Math.max(hi[i % 3], p[i]); }
  return Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
}

/** Per-vertex displacement between two flat position arrays. */
export function displacements(a, b) {
  const out = new Float64Array(a.length / 3);
  for (let i = 0; i < out.length; i++) out[i] = Math.hypot(b[i * 3] - a[i * 3], b[i * 3 + 1] - a[i * 3 + 1], b[i * 3 + 2] - a[i * 3 + 2]);
  return out;
}

export function centroid(p, vs) {
  const c = [0, 0, 0];
  for (const v of vs) for (let k = 0; k < 3; k++) c[k] += p[v * 3 + k];
  return c.map((x) => x / vs.length);
}
