// Browser-side speed of the viewer (issue 5): time from a drag event to the frame that shows its
// result, updates per second while dragging, and bytes per update in each position encoding,
// for the 4,802-vertex cylinder, the 40,401-vertex bumpy plane and the same plane at 187,489
// vertices (issue 15: a multiresolution session, moves answered on a coarse level and the full
// resolution streamed by the background refinement after the drag), on loopback or through an
// emulated link (--via-link), in one run.
//
//   node bench/viewer_latency.mjs [--build build] [--moves 90] [--out bench/results] [--model NAME]
//       [--baseline-dist DIR] [--name viewer] [--via-link SPEC] [--page-query PARAMS]
//
// --page-query PARAMS (e.g. "updates=quantized&budget=149000") adds the viewer's own address
// parameters (web_viewer/src/app/config.ts) to every page the bench opens: its link-sized Watch
// updates (issue 45) among them. The results record it (JSON `page_query`, the .md's header).
//
// Through a link (issue 45): --via-link SPEC (e.g. 20mbit,40ms; the items of meshdeform-link
// --help) starts <build>/linkemu/meshdeform-link in front of each server's HTTP port, on
// loopback, and points Chromium at it, so that the page, its gRPC-Web calls and its Watch stream
// all cross the emulated line. The emulator models each TCP connection as its own line (rate and
// delay per direction, per connection, not shared): the browser's HTTP/1.1 connections (page,
// moves, the Watch stream) each get SPEC. The results name the link ("loopback" without the
// option) and carry the emulator's description and its byte and stall counters for the run. The
// "service alone" rows (the C++ load tester) stay on loopback either way.
//
// The coarse level (issue 44): on the multiresolution model the viewer draws the level the moves
// solved on while the button is down; "this, ?coarse=off" is the same build drawing the full mesh
// every frame, in the same run.
//
// Input delay (issue 44): for every pointer event of the drag, how long it waited before the
// page's main thread ran its first handler (performance.now() - event.timeStamp, measured by a
// listener the bench adds, so any build of the viewer can be measured), how many of the drag's
// events reached the page, and how long the drag took to issue (each mouse move is acknowledged
// only once the page took it: a blocked page stretches the drag). --baseline-dist measures
// another build of the viewer (e.g. the one before issue 44) in the same run, served by a second
// server, for a side-by-side comparison.
//
// Starts its own meshdeform-server (127.0.0.1, ephemeral ports) serving web_viewer/dist, drives
// Debian's headless Chromium (playwright-core from web_viewer/node_modules) with real mouse
// events at 60 Hz, and reads the viewer's own measurements (window.__meshdeform.metrics():
// pointermove -> first animation frame after that move's revision was uploaded). Writes
// <name>.md and <name>.json (default viewer.*). Not a test: no thresholds. Rendering is CPU (SwiftShader) here.
import { spawn, execSync } from "node:child_process";
import { createRequire } from "node:module";
import { existsSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import os from "node:os";
import path from "node:path";
import { fileURLToPath } from "node:url";

const repo = path.resolve(path.dirname(fileURLToPath(import.meta.url)), "..");
const require = createRequire(path.join(repo, "web_viewer/package.json"));
const { chromium } = require("playwright-core");

const args = Object.fromEntries(process.argv.slice(2).reduce((acc, a, i, all) => {
  if (a.startsWith("--")) acc.push([a.slice(2), all[i + 1]]);
  return acc;
}, []));
const build = path.resolve(repo, args.build ?? "build");
const moves = Number(args.moves ?? 90);
const out = path.resolve(repo, args.out ?? "bench/results");
const name = args.name ?? "viewer";
const serverPath = path.join(build, "server/transport/meshdeform-server");
const loadtestPath = path.join(build, "client_cpp/loadtest/meshdeform-loadtest");
const dist = path.join(repo, "web_viewer/dist");
const baselineDist = args["baseline-dist"] ? path.resolve(args["baseline-dist"]) : null;
const viaLink = args["via-link"] ?? null;
const pageQuery = args["page-query"] ?? "";
if ("page-query" in args && (!pageQuery || pageQuery.startsWith("--") || /[?#\s]/.test(pageQuery))) {
  console.error('--page-query needs address parameters without "?", e.g. --page-query "updates=quantized&budget=149000"'); process.exit(2);
}
const linkPath = path.join(build, "linkemu/meshdeform-link");
if ("via-link" in args && (!viaLink || viaLink.startsWith("--"))) {
  console.error("--via-link needs a link description, e.g. --via-link 20mbit,40ms"); process.exit(2);
}
for (const f of [serverPath, path.join(dist, "index.html"), ...(baselineDist ? [path.join(baselineDist, "index.html")] : [])]) {
  if (!existsSync(f)) { console.error(`missing ${f}: run ./scripts/build.sh and ./scripts/build-viewer.sh`); process.exit(2); }
}
if (viaLink && !existsSync(linkPath)) {
  console.error(`missing ${linkPath} (--via-link): build the meshdeform-link target (linkemu/) in ${build}, or give --build`); process.exit(2);
}

// Every server and emulator this bench starts, so that none outlives it (an error, an exit, a signal).
const children = new Set();
function track(child) {
  children.add(child);
  child.once("exit", () => children.delete(child));
  return child;
}
process.once("exit", () => { for (const c of children) c.kill("SIGTERM"); });
for (const signal of ["SIGINT", "SIGTERM"]) {
  process.once(signal, () => { console.error(`${signal}: stopping`); process.exit(130); });
}
/** Resolves when `child` has exited, or after `ms` (then false). */
function exited(child, ms) {
  if (child.exitCode !== null || child.signalCode !== null) return Promise.resolve(true);
  return new Promise((resolve) => {
    const timer = setTimeout(() => resolve(false), ms);
    child.once("exit", () => { clearTimeout(timer); resolve(true); });
  });
}
/** SIGTERM, a bounded wait, then SIGKILL. @return whether it exited on SIGTERM. */
async function stopChild(child, ms) {
  if (child.exitCode !== null || child.signalCode !== null) return true;
  child.kill("SIGTERM");
  if (await exited(child, ms)) return true;
  child.kill("SIGKILL");
  await exited(child, 2000);
  return false;
}

/**
 * Starts `file` (tracked) and resolves with `ready(stderr so far)`'s first non-null value, read
 * as its stderr grows (the server and the emulator announce their ports there). Rejects, with
 * the child killed and its stderr, when it fails to start, exits first or takes over `ms`.
 */
function spawnUntilReady(file, argv, stdio, what, ms, ready) {
  return new Promise((resolve, reject) => {
    const child = track(spawn(file, argv, { stdio }));
    let log = "", settled = false;
    const fail = (why) => {
      if (settled) return;
      settled = true;
      clearTimeout(timer);
      child.kill("SIGKILL");
      reject(new Error(`${what} ${why}${log ? "\n" + log.trim() : ""}`));
    };
    const timer = setTimeout(() => fail(`did not report listening within ${ms / 1000} s`), ms);
    child.once("error", (e) => fail(`could not start: ${e.message}`));
    child.once("close", (code, signal) => fail(`exited (${code ?? signal}) before listening`));
    child.stderr.on("data", (d) => {
      if (settled) return;
      log += d;
      const value = ready(log);
      if (value === null) return;
      settled = true;
      clearTimeout(timer);
      resolve({ child, value });
    });
  });
}

/** meshdeform-link in front of 127.0.0.1:`targetPort`, on loopback: resolves once it listens. */
async function startLink(targetPort) {
  const { child: link, value: event } = await spawnUntilReady(linkPath,
    ["--target", `127.0.0.1:${targetPort}`, "--link", viaLink, "--listen", "127.0.0.1:0"],
    ["ignore", "pipe", "pipe"], `meshdeform-link (${linkPath})`, 10_000, (log) => {
      const m = log.match(/\{"event":"listening"[^\n]*\}/);
      return m ? JSON.parse(m[0]) : null;
    });
  let stdout = "";
  link.stdout.on("data", (d) => { stdout += d; });
  const startedAt = performance.now();
  return {
    process: link, port: event.port, description: event.link,
    /** Stops the emulator and returns its counters (null when it printed none). */
    async stop() {
      const clean = await stopChild(link, 5000);
      let counters = null;
      try { counters = JSON.parse(stdout.trim().split("\n").pop()); } catch { /* killed, or no output */ }
      return { seconds: (performance.now() - startedAt) / 1000, stopped_cleanly: clean, counters };
    },
  };
}

// settle: how long the page is watched after the mouse is released (refinement revisions).
const models = [
  { sample: "cylinder", vertices: 4802, encodings: ["double", "float32", "meshopt"], settleMs: 1500 },
  { sample: "bumpy_plane", vertices: 40401, encodings: ["double", "float32", "meshopt"], settleMs: 1500 },
  // multires: the server moves it on a coarse level; the viewer draws that level during a drag
  // (issue 44), measured beside ?coarse=off (the full mesh drawn every frame).
  { sample: "bumpy_plane_large", vertices: 187489, encodings: ["float32", "meshopt"], settleMs: Number(args.settle ?? 20_000), multires: true },
].filter((m) => !args.model || m.sample === args.model);

async function startServerAlone(webRoot) {
  const { child: server, value: ports } = await spawnUntilReady(serverPath,
    ["--listen", "127.0.0.1:0", "--http-listen", "127.0.0.1:0", "--web-root", webRoot, "--log-level", "info"],
    ["ignore", "ignore", "pipe"], "server", 20_000, (log) => {
      const m = log.match(/"event":"http_listening"[^\n]*"port":(\d+)/);
      const g = log.match(/"event":"listening"[^\n]*"port":(\d+)/);
      return m && g ? { http: Number(m[1]), grpc: g[1] } : null;
    });
  return { server, url: `http://127.0.0.1:${ports.http}`, grpc: `127.0.0.1:${ports.grpc}`, httpPort: ports.http };
}

/** A server, and with --via-link the emulator in front of its HTTP port: `url` is what Chromium
 * opens (the emulator's port then), `grpc` the server's own gRPC port (the load tester's). */
async function startServer(webRoot = dist) {
  const s = await startServerAlone(webRoot);
  if (!viaLink) return { ...s, link: null };
  try {
    const link = await startLink(s.httpPort);
    return { ...s, url: `http://127.0.0.1:${link.port}`, direct_url: s.url, link };
  } catch (e) {
    await stopChild(s.server, 5000);
    throw e;
  }
}

/** Stops the emulator (first: its counters), then the server. @return the link's record or null. */
async function stopServer(s, viewer) {
  let link = null;
  if (s.link) {
    const r = await s.link.stop();
    link = { viewer, server_http_port: s.httpPort, emulator_port: s.link.port, ...r };
  }
  if (!(await stopChild(s.server, 10_000))) console.error("the server did not exit on SIGTERM within 10 s: killed");
  return link;
}

const quantile = (xs, q) => {
  if (!xs.length) return NaN;
  const s = [...xs].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
};
const mean = (xs) => xs.reduce((a, b) => a + b, 0) / Math.max(xs.length, 1);

/** Added to every page before its scripts: the input delay of each pointer event while on. */
function inputProbe() {
  const b = { on: false, delays: [], events: 0 };
  window.__bench = b;
  window.addEventListener("pointermove", (e) => {
    if (!b.on) return;
    b.delays.push(Math.max(0, performance.now() - e.timeStamp));
    b.events += e.getCoalescedEvents?.().length || 1;
  }, { capture: true });
}

async function measure(browser, url, model, encoding, viewer = "this", query = "") {
  const ctx = await browser.newContext({ viewport: { width: Number(args.width ?? 1200), height: Number(args.height ?? 800) } });
  await ctx.addInitScript(inputProbe);
  const page = await ctx.newPage();
  page.setDefaultTimeout(300_000);
  await page.goto(`${url}/?sample=${model.sample}&encoding=${encoding}${query}${pageQuery ? `&${pageQuery}` : ""}`);
  await page.waitForFunction(() => window.__meshdeform?.ready, null, { timeout: 300_000, polling: 100 });
  await page.waitForTimeout(1500);  // let the first refinement of nothing settle
  await page.evaluate(() => window.__meshdeform.resetMetrics());
  const p = await page.evaluate(() => window.__meshdeform.handleScreenPoint());
  await page.mouse.move(p.x, p.y);
  await page.mouse.down();
  await page.evaluate(() => (window.__bench.on = true));
  const t0 = performance.now();
  for (let i = 1; i <= moves; i++) {
    const a = (2 * Math.PI * i) / moves;
    await page.mouse.move(p.x + 60 * Math.sin(a), p.y - 40 * (1 - Math.cos(a)));
    const next = t0 + i * (1000 / 60);
    const wait = next - performance.now();
    if (wait > 0) await new Promise((r) => setTimeout(r, wait));
  }
  const dragSeconds = (performance.now() - t0) / 1000;
  const probe = await page.evaluate(() => {
    window.__bench.on = false;
    return { delays: window.__bench.delays, events: window.__bench.events };
  });
  await page.mouse.up();
  const upAt = await page.evaluate(() => performance.now());
  await page.waitForTimeout(model.settleMs);
  const m = await page.evaluate(() => window.__meshdeform.metrics());
  await ctx.close();
  const frames = m.dragToFrameMs;
  // After the release: the background refinement's revisions (full resolution on a
  // multiresolution session), when each was on screen.
  const after = m.renderedAt.map((t, i) => ({ t: t - upAt, refinement: m.renderedRefinement[i], converged: m.renderedConverged[i] }))
    .filter((u) => u.t >= 0 && u.refinement);
  return {
    model: model.sample, vertices: model.vertices, encoding, viewer, link: viaLink ?? "loopback", page_query: pageQuery,
    drag_events: moves, drag_seconds: dragSeconds, nominal_drag_seconds: moves / 60,
    input_delay_ms: { p50: quantile(probe.delays, 0.5), p95: quantile(probe.delays, 0.95), max: probe.delays.length ? Math.max(...probe.delays) : NaN },
    pointer_events_handled: probe.events,
    worker_frames: m.workerMs?.length ?? 0,
    own_frames: frames.length, updates_per_second: frames.length / dragSeconds,
    drag_to_frame_ms: { p50: quantile(frames, 0.5), p95: quantile(frames, 0.95), max: Math.max(...frames), p99: quantile(frames, 0.99) },
    updates_received: m.updateBytes.length,
    frame_work_ms: { p50: quantile(m.frameWorkMs, 0.5), p95: quantile(m.frameWorkMs, 0.95), frames: m.frameWorkMs.length },
    bytes_per_update_mean: mean(m.updateBytes),
    dense_double_bytes: 24 * model.vertices,
    dense_float32_bytes: 12 * model.vertices,
    settle_ms: model.settleMs,
    refinement_after_release: {
      frames: after.length,
      first_ms: after.length ? after[0].t : null,
      last_ms: after.length ? after[after.length - 1].t : null,
      converged: after.some((u) => u.converged),
    },
  };
}

/** The same edit loop without a browser: the C++ load tester (native gRPC), one session, one
 * move in flight, ticks at 60 Hz, one watcher: what the service and the wire sustain. */
function serviceAlone(grpc, model) {
  if (!existsSync(loadtestPath)) return null;
  const json = path.join(os.tmpdir(), `meshdeform-viewer-bench-${process.pid}-${model.sample}.json`);
  execSync(`${loadtestPath} --server ${grpc} --sessions 1 --sample ${model.sample} --rate 60 --duration 10 --watchers 1 --iterations 2 --json ${json}`,
    { stdio: "ignore", timeout: 120_000 });
  const j = JSON.parse(readFileSync(json, "utf8"));
  return { model: model.sample, moves_per_second: j.moves.per_second_total, latency_ms: j.moves.latency_ms, server_solve_ms: j.moves.server_solve_ms,
    link: "loopback" };
}

const main = await startServer();
const { url, grpc } = main;
const baseline = baselineDist ? await startServer(baselineDist) : null;
if (viaLink) {
  console.log(`through meshdeform-link ${viaLink} (${main.link.description}): ${url} -> ${main.direct_url}` +
    (baseline ? `; baseline ${baseline.url} -> ${baseline.direct_url}` : ""));
}
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM_PATH || "/usr/bin/chromium",
  args: ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
});
const rows = [];
const alone = [];
const linkRuns = [];
try {
  for (const model of models) {
    const a = serviceAlone(grpc, model);
    if (a) {
      alone.push(a);
      console.log(`${a.model} service alone: ${a.moves_per_second.toFixed(1)} moves/s, latency p50 ${a.latency_ms.p50.toFixed(1)} ms, solve p50 ${a.server_solve_ms.p50.toFixed(1)} ms`);
    }
  }
  for (const model of models) {
    for (const encoding of model.encodings) {
      // This build and the baseline build side by side, model by model (the machine is noisy).
      const variants = [["this", url, ""], ...(model.multires ? [["this, ?coarse=off", url, "&coarse=off"]] : []),
        ...(baseline ? [["baseline", baseline.url, ""]] : [])];
      for (const [viewer, at, query] of variants) {
        const r = await measure(browser, at, model, encoding, viewer, query);
        rows.push(r);
        console.log(`${r.model} ${r.encoding} (${viewer}): ${r.updates_per_second.toFixed(1)} updates/s, drag->frame p50 ${r.drag_to_frame_ms.p50.toFixed(0)} ms, ` +
          `frame work p50 ${r.frame_work_ms.p50.toFixed(1)} ms, drag took ${r.drag_seconds.toFixed(1)} s (nominal ${r.nominal_drag_seconds.toFixed(1)}), ` +
          `input delay p50 / p95 / max ${r.input_delay_ms.p50.toFixed(1)} / ${r.input_delay_ms.p95.toFixed(1)} / ${r.input_delay_ms.max.toFixed(1)} ms, ` +
          `${r.pointer_events_handled} of ${r.drag_events} pointer events, ` +
          `p95 ${r.drag_to_frame_ms.p95.toFixed(0)} ms, ${(r.bytes_per_update_mean / 1024).toFixed(1)} KiB/update`);
      }
    }
  }
} finally {
  let version = "unknown";
  try {
    version = browser.version();
    await browser.close();
  } finally {
    // The emulator goes first (after the browser's connections closed): its counters cover the run.
    for (const [s, viewer] of [[main, "this"], [baseline, "baseline"]]) {
      const link = s ? await stopServer(s, viewer) : null;
      if (link) linkRuns.push(link);
    }
  }
  var chromiumVersion = version;
}

let git = "unknown";
try { git = execSync("git describe --always --dirty", { cwd: repo }).toString().trim(); } catch { /* not a checkout */ }
const machine = {
  date_utc: new Date().toISOString(), cpu_model: os.cpus()[0]?.model ?? "unknown", hardware_threads: os.cpus().length,
  load_average: os.loadavg().map((x) => x.toFixed(2)).join(" "), chromium: chromiumVersion, node: process.version, git_revision: git,
  rendering: "headless Chromium, SwiftShader (CPU) WebGL", drag: `${moves} mouse events at 60 Hz on a loop of 60 x 80 px`,
};
// The link every browser row used: "loopback", or the emulator's settings and counters per server.
const link = !viaLink ? "loopback" : {
  spec: viaLink, description: main.link.description, emulator: path.relative(repo, linkPath), listen: "127.0.0.1 (loopback)",
  per_connection: "each TCP connection is its own emulated line (rate, delay, queue per direction per connection, not shared)",
  service_alone: "loopback (the load tester connects to the server's gRPC port directly)",
  servers: linkRuns,
};
mkdirSync(out, { recursive: true });
writeFileSync(path.join(out, `${name}.json`), JSON.stringify({ machine, rows, service_alone: alone, link, page_query: pageQuery }, null, 2) + "\n");
const f = (x, d = 0) => (Number.isFinite(x) ? x.toFixed(d) : "-");
let md = `# Viewer: drag to frame, updates per second, bytes per update\n\n`;
md += `Made by \`node bench/viewer_latency.mjs ${process.argv.slice(2).join(" ")}\` on ${machine.date_utc} (${machine.cpu_model}, ${machine.hardware_threads} threads, ` +
  `load ${machine.load_average}; Chromium ${machine.chromium}, ${machine.rendering}; git ${machine.git_revision}). ` +
  (viaLink
    ? `Server and browser on one machine; the browser through meshdeform-link \`--link ${viaLink}\` (${link.description}; each TCP connection its own line), ` +
      `the service-alone rows on loopback`
    : `Server and browser on one machine, loopback`) +
  `; ${machine.drag}; 2 outer iterations per move, one move in flight, newest target wins` +
  (pageQuery ? `; every page opened with \`&${pageQuery}\`` : "") + `.\n\n`;
md += `| model | #V | encoding | viewer | updates/s while dragging | drag -> frame p50 / p95 / max (ms) | frame work p50 (ms) | bytes / update (mean) | dense doubles | dense float32 |\n`;
md += `|---|---:|---|---|---:|---|---:|---:|---:|---:|\n`;
for (const r of rows) {
  md += `| ${r.model} | ${r.vertices.toLocaleString("en")} | ${r.encoding} | ${r.viewer} | ${f(r.updates_per_second, 1)} | ${f(r.drag_to_frame_ms.p50)} / ${f(r.drag_to_frame_ms.p95)} / ${f(r.drag_to_frame_ms.max)} | ${f(r.frame_work_ms.p50, 1)} | ` +
    `${Math.round(r.bytes_per_update_mean).toLocaleString("en")} | ${r.dense_double_bytes.toLocaleString("en")} | ${r.dense_float32_bytes.toLocaleString("en")} |\n`;
}
md += `\nInput while dragging (issue 44): each pointer event's wait before the page ran its first handler, the events that reached the page, ` +
  `and how long the ${moves}-event drag took to issue (nominal ${(moves / 60).toFixed(1)} s at 60 Hz; a page that does not take input stretches it)` +
  `${baseline ? "; \"baseline\" is the viewer build given with --baseline-dist, on a second server of the same binary" : ""}:\n\n`;
md += `| model | encoding | viewer | input delay p50 / p95 / max (ms) | pointer events handled | drag issued in (s) |\n|---|---|---|---|---:|---:|\n`;
for (const r of rows) {
  md += `| ${r.model} | ${r.encoding} | ${r.viewer} | ${f(r.input_delay_ms.p50, 1)} / ${f(r.input_delay_ms.p95, 1)} / ${f(r.input_delay_ms.max, 1)} | ${r.pointer_events_handled} of ${r.drag_events} | ${f(r.drag_seconds, 1)} |\n`;
}
md += `\nframe work: main-thread time per rendered frame (normals + WebGL calls); the rasterizing itself runs in Chromium's GPU process, on the CPU here.\n`;
md += `\nAfter the release (the background refinement: on the ${(187489).toLocaleString("en")}-vertex plane, a multiresolution session, the moves ` +
  `above are coarse-level solves prolonged to full resolution, and these revisions are full-resolution solves):\n\n`;
md += `| model | encoding | viewer | watched (s) | refinement frames | first / last after release (ms) | converged within the watch |\n|---|---|---|---:|---:|---|---|\n`;
for (const r of rows) {
  const a = r.refinement_after_release;
  md += `| ${r.model} | ${r.encoding} | ${r.viewer} | ${f(r.settle_ms / 1000, 1)} | ${a.frames} | ${a.frames ? `${f(a.first_ms)} / ${f(a.last_ms)}` : "-"} | ${a.converged ? "yes" : "no"} |\n`;
}
if (alone.length) {
  md += `\nThe same loop without a browser (meshdeform-loadtest, native gRPC, same server, 60 Hz ticks, one move in flight, one watcher):\n\n`;
  md += `| model | moves/s | latency p50 / p95 (ms) | server solve p50 (ms) |\n|---|---:|---|---:|\n`;
  for (const a of alone) md += `| ${a.model} | ${f(a.moves_per_second, 1)} | ${f(a.latency_ms.p50, 1)} / ${f(a.latency_ms.p95, 1)} | ${f(a.server_solve_ms.p50, 1)} |\n`;
}
md += `\nbytes / update: the serialized DeformUpdate of every Watch message received during and right after the drag ` +
  `(deltas of the changed vertices: indices + positions; refinement revisions included). Dense: every position, for comparison.\n`;
if (!viaLink) {
  md += `\nLink: loopback (no emulator).\n`;
} else {
  md += `\nLink: \`${viaLink}\` through \`${link.emulator}\` on loopback: ${link.description}. ` +
    `Each TCP connection the browser opens is its own line with these settings (not a shared bottleneck). ` +
    `drag -> frame p99 is in the JSON (\`drag_to_frame_ms.p99\`). The emulator's counters over the whole run ` +
    `(page loads, every row of its server; "down" is server to browser):\n\n`;
  md += `| server | ran (s) | connections | down: bytes delivered / mean / max chunk delay (ms) | up: bytes delivered / mean / max chunk delay (ms) | full-queue waits down / up |\n`;
  md += `|---|---:|---:|---|---|---:|\n`;
  for (const l of linkRuns) {
    const c = l.counters;
    const dir = (d) => `${d.bytes_delivered.toLocaleString("en")} / ${f(d.mean_chunk_delay_ms, 1)} / ${f(d.max_chunk_delay_ms, 1)}`;
    md += c ? `| ${l.viewer} | ${f(l.seconds, 1)} | ${c.connections_accepted} | ${dir(c.down)} | ${dir(c.up)} | ${c.down.full_queue_waits} / ${c.up.full_queue_waits} |\n`
      : `| ${l.viewer} | ${f(l.seconds, 1)} | - | no counters (the emulator did not exit cleanly) | - | - |\n`;
  }
}
writeFileSync(path.join(out, `${name}.md`), md);
console.log(`wrote ${path.join(out, `${name}.md`)}`);
