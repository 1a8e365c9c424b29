#!/usr/bin/env node
// bench_view: the goals of `hapticpd view` (#21), measured in one run on this
// machine (tests/bench/README.md "Viewer" says what exactly is measured).
//
//   1. 8 WebSocket clients speaking the page's protocol (every message read
//      and parsed, each mesh fetched once by hash, a ping a second) on one
//      scene against none: the update rate of a 1 kHz simulated device
//      session (server answers per second), alternating 0 and 8 clients.
//   2. One headless Chromium page at 1280x800 in software WebGL (SwiftShader)
//      with the Stanford bunny and a demo-like device session (a stick
//      sliding over the bunny's back) on the same machine: frames drawn per
//      second over 10 s, and the worst 1 s window.
//   3. Pose-to-screen latency in that page: from the server's stamp on the
//      pose frame (Poses.server_time_ns, steady clock) to the page's frame
//      that drew it (lastPoseRenderedAt, performance.now()), p50/p99.
//
// Usage (from the repository root, after building the release preset's
// hapticpd and browser_node_modules targets):
//   node tests/bench/bench_view.mjs [--run-s 5] [--pairs 5] [--fps-s 10] [--clients 8]
//                                   [--no-full] [--no-readme] [--json] [--trace FILE]
// It prints the load average at its start and the table, and writes the
// table into tests/bench/README.md between the bench_view markers.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { Server, Viewer, launchBrowser, openPage, waitView, deps, config, httpGet, repoRoot,
         sleep } from '../browser/lib/harness.mjs';

const args = process.argv.slice(2);
const opt = (name, def) => {
  const i = args.indexOf(name);
  return i >= 0 ? Number(args[i + 1]) : def;
};
const RUN_S = opt('--run-s', 5);
const PAIRS = opt('--pairs', 5);
const FPS_S = opt('--fps-s', 10);
const CLIENTS = opt('--clients', 8);
const WRITE_README = !args.includes('--no-readme');
const TRACE = args.includes('--trace') ? args[args.indexOf('--trace') + 1] : null;
const here = path.dirname(fileURLToPath(import.meta.url));
const README = path.join(here, 'README.md');

const quantile = (xs, q) => {
  const s = [...xs].sort((a, b) => a - b);
  if (!s.length) return NaN;
  const i = Math.min(s.length - 1, Math.max(0, Math.ceil(q * s.length) - 1));
  return s[i];
};
const mean = (xs) => xs.reduce((a, b) => a + b, 0) / xs.length;
const hrMs = () => Number(process.hrtime.bigint()) / 1e6;  // CLOCK_MONOTONIC, as the server's steady_clock

// ---------------------------------------------------------------------------
// A WebSocket client that does what the page does with the protocol.
class ProtocolClient {
  constructor(viewer) {
    const { WebSocket } = deps();
    this.viewer = viewer;
    this.messages = 0;
    this.bytes = 0;
    this.byType = {};
    this.meshes = new Set();
    this.meshBytes = 0;
    const u = new URL(viewer.url('/ws'));
    u.protocol = 'ws:';
    this.ws = new WebSocket(u.toString());
    this.open = new Promise((resolve, reject) => {
      this.ws.on('open', resolve);
      this.ws.on('error', reject);
    });
    this.ws.on('message', (data) => {
      this.messages++;
      this.bytes += data.length;
      const msg = JSON.parse(data.toString());
      this.byType[msg.type] = (this.byType[msg.type] || 0) + 1;
      this.fetchMeshes(msg);
    });
    this.ping = setInterval(() => {
      if (this.ws.readyState === 1) this.ws.send(JSON.stringify({ type: 'ping', t: hrMs() }));
    }, 1000);
  }
  fetchMeshes(x) {
    if (Array.isArray(x)) { x.forEach((y) => this.fetchMeshes(y)); return; }
    if (!x || typeof x !== 'object') return;
    for (const [k, v] of Object.entries(x)) {
      if (k === 'mesh' && typeof v === 'string' && /^[0-9a-f]{32}$/.test(v) && !this.meshes.has(v)) {
        this.meshes.add(v);
        httpGet(this.viewer.url(`/mesh/${v}`), { timeoutMs: 30000 })
          .then((r) => { this.meshBytes += r.body.length; }).catch(() => {});
      } else if (typeof v === 'object') {
        this.fetchMeshes(v);
      }
    }
  }
  close() { clearInterval(this.ping); this.ws.terminate(); }
}

async function deviceRate(server, scene, extra = {}) {
  const dev = server.device(scene, { script: 'press', duration: RUN_S, ...extra });
  const { code, json } = await dev.result;
  if (code !== 0 || !json) throw new Error(`device session failed (exit ${code}):\n${dev.output()}`);
  return { rate: json.updates / json.elapsed_s, json };
}

// ---------------------------------------------------------------------------
async function benchClients() {
  const server = await Server.start();
  await server.createScene('clients');
  await server.inject('clients', 'block', 'box:0.03,0.03,0.02', '0,0,0');
  await server.inject('clients', 'ball', 'sphere:0.02', '0.06,0,0.02');
  const viewer = await Viewer.start({ server, scene: 'clients' });
  const r = { zero: [], many: [], perClient: [] };
  for (let i = 0; i < PAIRS; i++) {
    const a = await deviceRate(server, 'clients');
    r.zero.push(a.rate);
    const clients = Array.from({ length: CLIENTS }, () => new ProtocolClient(viewer));
    await Promise.all(clients.map((c) => c.open));
    const m0 = clients.map((c) => c.messages);
    const t0 = hrMs();
    const b = await deviceRate(server, 'clients');
    const dt = (hrMs() - t0) / 1000;
    r.many.push(b.rate);
    r.perClient.push(...clients.map((c, k) => (c.messages - m0[k]) / dt));
    r.sample = { byType: clients[0].byType, meshes: clients[0].meshes.size, bytes: clients[0].bytes };
    clients.forEach((c) => c.close());
    console.log(`  pair ${i + 1}: 0 clients ${a.rate.toFixed(1)}/s, ${CLIENTS} clients ` +
                `${b.rate.toFixed(1)}/s (each client ${mean(r.perClient.slice(-CLIENTS)).toFixed(0)} msgs/s)`);
  }
  r.health = await viewer.health().catch(() => null);
  await viewer.kill('SIGTERM');
  await server.proc.kill('SIGTERM');
  // Medians: one session slowed by something else on this shared machine
  // (a compiler, another test) moves a mean by percents.
  r.ratio = quantile(r.many, 0.5) / quantile(r.zero, 0.5);
  return r;
}

// ---------------------------------------------------------------------------
async function benchPage(viewerExtra = []) {
  const bunny = path.join(config.modelsDir, 'stanford-bunny.obj');
  const haveBunny = fs.existsSync(bunny);
  if (!haveBunny) console.log(`  ${bunny} is absent: a torus knot stands in for the bunny`);
  const server = await Server.start();
  await server.createScene('bunny');
  // The bunny turned z-up (+90 deg about x), resting on z = 0 around the origin.
  if (haveBunny) {
    await server.inject('bunny', 'bunny', `mesh:${bunny}`, '0.017,-0.0003,-0.033,0.70710678,0.70710678,0,0');
  } else {
    await server.inject('bunny', 'knot', 'torusknot', '0,0,0.05');
  }
  await server.inject('bunny', 'floor', 'box:0.15,0.15,0.005', '0,0,-0.005');
  const viewer = await Viewer.start({ server, scene: 'bunny', extra: viewerExtra });
  const browser = await launchBrowser();
  const page = await openPage(browser, viewer.url('/'), { timeoutMs: 60000 });
  await waitView(page, () => __count(window.hapticpdView.bodies) === 2, { timeoutMs: 60000,
                 what: 'the bunny scene shown' });

  // --trace FILE: a DevTools trace from the session's start to the end of
  // the window (chrome://tracing or the DevTools Performance panel read it).
  if (TRACE && viewerExtra.length === 0) {
    await page.tracing.start({ path: TRACE, categories: ['devtools.timeline', 'v8', 'gpu',
      'disabled-by-default-devtools.timeline', 'toplevel', 'blink', 'cc', 'viz'] });
  }
  // The demo's kind of session: a stick sliding over the bunny's back (local model on).
  const session = server.device('bunny', { script: 'slide', duration: FPS_S + 8,
                                           extra: ['--travel', '0.03'] });
  await waitView(page, () => Object.keys(window.hapticpdView.probes || {}).length > 0,
                 { timeoutMs: 20000, what: 'the probe shown' });

  // Clock mapping: page performance.now() -> this process's CLOCK_MONOTONIC
  // (ms), from the round trip with the least time (NTP-like; error <= rtt/2).
  const calibrate = async () => {
    let best = null;
    for (let i = 0; i < 40; i++) {
      const t0 = hrMs();
      const p = await page.evaluate(() => performance.now());
      const t1 = hrMs();
      if (!best || t1 - t0 < best.rtt) best = { rtt: t1 - t0, offset: (t0 + t1) / 2 - p };
    }
    return best;
  };
  const cal0 = await calibrate();

  // In the page: every frame's framesRendered, and each pose's first drawing.
  await page.evaluate(() => {
    window.__bench = { frames: [], poses: new Map() };
    const tick = () => {
      const v = window.hapticpdView;
      window.__bench.frames.push([performance.now(), v.framesRendered]);
      if (v.lastPoseServerTimeNs && !window.__bench.poses.has(v.lastPoseServerTimeNs)) {
        window.__bench.poses.set(v.lastPoseServerTimeNs, v.lastPoseRenderedAt);
      }
    };
    // Sampled once per animation frame, after the page's own frame callback
    // (registered first): a timer every few milliseconds would itself wake
    // the page's main thread hundreds of times a second.
    const loop = () => { if (window.__bench.on) { tick(); requestAnimationFrame(loop); } };
    window.__bench.on = true;
    requestAnimationFrame(loop);
  });
  await sleep(FPS_S * 1000);  // the measurement window itself
  const got = await page.evaluate(() => {
    window.__bench.on = false;
    // The window ends now, not at the last frame: a page frozen at the end
    // of it counts.
    window.__bench.frames.push([performance.now(), window.hapticpdView.framesRendered]);
    return { frames: window.__bench.frames, poses: [...window.__bench.poses.entries()] };
  });
  if (TRACE && viewerExtra.length === 0) await page.tracing.stop();
  const cal1 = await calibrate();
  const state = await page.evaluate(() => ({ probes: Object.keys(window.hapticpdView.probes).length,
                                             bodies: window.hapticpdView.bodies }));
  const dev = await session.result;
  await browser.close();
  await viewer.kill('SIGTERM');
  await server.proc.kill('SIGTERM');

  // Frames per second: over the whole window, and the worst 1 s window.
  const f = got.frames;
  const span = (f[f.length - 1][0] - f[0][0]) / 1000;
  const fpsMean = (f[f.length - 1][1] - f[0][1]) / span;
  let worst = Infinity;
  for (let i = 0, j = 0; i < f.length; i++) {
    while (j < f.length && f[j][0] - f[i][0] < 1000) j++;
    if (j >= f.length) break;
    worst = Math.min(worst, (f[j][1] - f[i][1]) / ((f[j][0] - f[i][0]) / 1000));
  }

  // The longest time without a new frame, and when (s into the window).
  let gap = 0, gapAt = 0;
  for (let i = 1, last = 0; i < f.length; i++) {
    if (f[i][1] === f[i - 1][1] && i < f.length - 1) continue;  // the window's end counts
    const g = f[i][0] - f[last][0];
    if (g > gap) { gap = g; gapAt = (f[last][0] - f[0][0]) / 1000; }
    last = i;
  }

  // Latency: the pose's server stamp vs its first drawing, on one clock.
  const offset = (cal0.offset + cal1.offset) / 2;
  const lat = got.poses.map(([serverNs, renderedAt]) => renderedAt + offset - Number(serverNs) / 1e6)
    .filter((x) => Number.isFinite(x));
  return {
    haveBunny, fpsMean, fpsWorst: worst, gap, gapAt, span, frames: f[f.length - 1][1] - f[0][1],
    latP50: quantile(lat, 0.5), latP99: quantile(lat, 0.99), latN: lat.length,
    calRtt: Math.max(cal0.rtt, cal1.rtt), calDrift: Math.abs(cal1.offset - cal0.offset),
    device: dev.json, state,
  };
}

// ---------------------------------------------------------------------------
const load0 = os.loadavg();
const started = new Date();
console.log(`bench_view ${started.toISOString()}: load average at start ${load0.map((x) => x.toFixed(2)).join(' ')} ` +
            `(${os.cpus().length} cores); hapticpd ${config.cli}; chromium ${config.chromium}`);
console.log(`1. ${CLIENTS} WebSocket clients vs none: ${PAIRS} pairs of ${RUN_S} s device sessions`);
const c = await benchClients();
console.log(`2./3. one Chromium page 1280x800 (SwiftShader), bunny scene, slide session: ${FPS_S} s`);
const p = await benchPage();
let full = null;
if (!args.includes('--no-full')) {
  console.log(`   again with every mesh drawn in full (--display-triangles 0): ${FPS_S} s`);
  full = await benchPage(['--display-triangles', '0']);
}
const load1 = os.loadavg();

const pct = (x) => `${(100 * (x - 1)).toFixed(1)} %`;
const rows = [
  ['update rate, 0 clients (median of runs)', `${quantile(c.zero, 0.5).toFixed(1)} /s (${c.zero.map((x) => x.toFixed(0)).join(', ')})`, ''],
  [`update rate, ${CLIENTS} WebSocket clients (median)`, `${quantile(c.many, 0.5).toFixed(1)} /s (${c.many.map((x) => x.toFixed(0)).join(', ')})`, ''],
  [`ratio ${CLIENTS} / 0 clients`, `${c.ratio.toFixed(4)} (${pct(c.ratio)})`, 'change < 2 %: ' + (Math.abs(c.ratio - 1) < 0.02 ? 'met' : 'not met')],
  ['messages per client', `${mean(c.perClient).toFixed(0)} /s`, ''],
  [`page frames/s, mean over ${p.span.toFixed(1)} s`, `${p.fpsMean.toFixed(1)} (${p.frames} frames)`, '>= 30: ' + (p.fpsMean >= 30 ? 'met' : 'not met')],
  ['page frames/s, worst 1 s window', p.fpsWorst.toFixed(1), ''],
  ...(full ? [['the same with every mesh in full (`--display-triangles 0`): mean, worst 1 s',
               `${full.fpsMean.toFixed(1)}, ${full.fpsWorst.toFixed(1)} (default / full ${(p.fpsMean / full.fpsMean).toFixed(2)})`, '']] : []),
  ['longest time without a new frame', `${p.gap.toFixed(0)} ms (at ${p.gapAt.toFixed(1)} s)`, ''],
  [`pose-to-screen latency p50 / p99 (${p.latN} poses)`, `${p.latP50.toFixed(1)} / ${p.latP99.toFixed(1)} ms`, 'reported'],
  ['clock mapping error bound (rtt/2, drift)', `${(p.calRtt / 2).toFixed(2)} ms, ${p.calDrift.toFixed(2)} ms`, ''],
  ['device session during the page run', `${(p.device.updates / p.device.elapsed_s).toFixed(0)} updates/s, loop ${p.device.loop_hz.toFixed(0)} Hz`, ''],
];
const table = ['| quantity | measured | goal |', '|---|---|---|',
  ...rows.map((r) => `| ${r.join(' | ')} |`)].join('\n');
console.log(`\n${table}\n`);
console.log(`load average at the end ${load1.map((x) => x.toFixed(2)).join(' ')}`);
if (args.includes('--json')) console.log(JSON.stringify({ clients: c, page: p, load0, load1 }));

if (WRITE_README) {
  const begin = '<!-- bench_view:begin (generated by tests/bench/bench_view.mjs) -->';
  const end = '<!-- bench_view:end -->';
  const body = `${begin}\nMeasured by ` +
    `\`node tests/bench/bench_view.mjs\` (load average at start ${load0.map((x) => x.toFixed(2)).join(' ')}, ` +
    `${os.cpus().length} cores; ${CLIENTS} clients, ${PAIRS} pairs of ${RUN_S} s sessions; ` +
    `${p.haveBunny ? 'the Stanford bunny' : 'a torus knot (no bunny found)'}):\n\n${table}\n${end}`;
  let text = fs.readFileSync(README, 'utf8');
  if (text.includes(begin) && text.includes(end)) {
    text = text.slice(0, text.indexOf(begin)) + body + text.slice(text.indexOf(end) + end.length);
  } else {
    text = `${text.trimEnd()}\n\n## Viewer\n\n${body}\n`;
  }
  fs.writeFileSync(README, text);
  console.log(`table written to ${path.relative(repoRoot, README)}`);
}
process.exit(0);
