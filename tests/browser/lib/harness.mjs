// The harness behind tests/browser/*.mjs and tests/bench/bench_view.mjs:
// real `hapticpd serve` and `hapticpd view` processes on free loopback
// ports with a temporary state directory, Debian's chromium-headless-shell
// through puppeteer-core, and cleanup of every process started here on any
// exit (normal, exception, SIGINT/SIGTERM, the test's own deadline).
//
// Environment (set by tests/CMakeLists.txt; defaults for a run by hand from
// the repository root):
//   HAPTICPD_CLI            the hapticpd executable (build/release/hapticpd)
//   HAPTICPD_CHROMIUM       chromium-headless-shell (/usr/bin/chromium-headless-shell)
//   HAPTICPD_NODE_MODULES   the folder holding puppeteer-core and ws
//                           (build/release/tests/browser/node_modules)
//   HAPTICPD_MODELS_DIR     the shared meshes (../shared/models)
//   HAPTICPD_SCREENSHOT     where test (a) writes its screenshot
//   HAPTICPD_TEST_DEADLINE_S the whole test's deadline (default 100 s)
import { spawn, execFile } from 'node:child_process';
import { createRequire } from 'node:module';
import fs from 'node:fs';
import net from 'node:net';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

export const SKIP = 77;  // CTest SKIP_RETURN_CODE

const here = path.dirname(fileURLToPath(import.meta.url));
export const repoRoot = path.resolve(here, '..', '..', '..');

export const config = {
  cli: process.env.HAPTICPD_CLI || path.join(repoRoot, 'build', 'release', 'hapticpd'),
  chromium: process.env.HAPTICPD_CHROMIUM || '/usr/bin/chromium-headless-shell',
  modelsDir: process.env.HAPTICPD_MODELS_DIR || path.join(repoRoot, '..', 'shared', 'models'),
  screenshot: process.env.HAPTICPD_SCREENSHOT ||
      path.join(repoRoot, 'build', 'viewer-screenshot.png'),
  deadlineS: Number(process.env.HAPTICPD_TEST_DEADLINE_S || 100),
};

// ---------------------------------------------------------------------------
// npm dependencies: installed by `npm ci` into the build tree (never in git).

let depsCache = null;
export function deps() {
  if (depsCache) return depsCache;
  const candidates = [
    process.env.HAPTICPD_NODE_MODULES,
    path.join(repoRoot, 'build', 'release', 'tests', 'browser', 'node_modules'),
    path.join(here, '..', 'node_modules'),
  ].filter(Boolean);
  for (const dir of candidates) {
    if (fs.existsSync(path.join(dir, 'puppeteer-core', 'package.json'))) {
      const req = createRequire(path.join(dir, '..', 'package.json'));
      depsCache = { puppeteer: req('puppeteer-core'), WebSocket: req('ws'), dir };
      return depsCache;
    }
  }
  throw new Error(`puppeteer-core is not installed in any of: ${candidates.join(', ')}. ` +
                  'Build the release preset (it runs `npm ci` into build/release/tests/browser), ' +
                  'or run `npm ci --prefix tests/browser`, or set HAPTICPD_NODE_MODULES.');
}

// ---------------------------------------------------------------------------
// Processes started here, killed on any exit.

const children = new Set();
const tmpDirs = new Set();
let cleanedUp = false;

function killAllSync() {
  for (const c of children) {
    if (c.exitCode === null && c.signalCode === null) {
      try { c.kill('SIGKILL'); } catch { /* already gone */ }
    }
  }
  children.clear();
  for (const d of tmpDirs) {
    try { fs.rmSync(d, { recursive: true, force: true }); } catch { /* best effort */ }
  }
  tmpDirs.clear();
}

process.on('exit', killAllSync);
for (const sig of ['SIGINT', 'SIGTERM', 'SIGHUP']) {
  process.on(sig, () => {
    console.error(`\n${sig}: stopping every process this test started`);
    killAllSync();
    process.exit(128 + (sig === 'SIGINT' ? 2 : sig === 'SIGTERM' ? 15 : 1));
  });
}

export function tmpDir(prefix = 'hapticpd-browser-') {
  const d = fs.mkdtempSync(path.join(os.tmpdir(), prefix));
  tmpDirs.add(d);
  return d;
}

// A started process with its output kept (the last 400 lines) for failure reports.
export class Proc {
  constructor(name, args, opts = {}) {
    this.name = name;
    this.args = args;
    this.lines = [];
    this.waiters = [];
    this.child = spawn(opts.command || config.cli, args, {
      stdio: ['ignore', 'pipe', 'pipe'],
      env: { ...process.env, ...(opts.env || {}) },
    });
    children.add(this.child);
    this.exited = new Promise((resolve) => {
      this.child.on('exit', (code, signal) => {
        children.delete(this.child);
        this.exitCode = code;
        this.exitSignal = signal;
        resolve({ code, signal });
      });
      this.child.on('error', (err) => {
        this.lines.push(`spawn error: ${err.message}`);
        children.delete(this.child);
        this.exitCode = -1;
        resolve({ code: -1, signal: null, error: err });
      });
    });
    for (const stream of [this.child.stdout, this.child.stderr]) {
      let buf = '';
      stream.setEncoding('utf8');
      stream.on('data', (chunk) => {
        buf += chunk;
        let i;
        while ((i = buf.indexOf('\n')) >= 0) {
          this.onLine(buf.slice(0, i));
          buf = buf.slice(i + 1);
        }
      });
      stream.on('end', () => { if (buf) this.onLine(buf); });
    }
  }
  get pid() { return this.child.pid; }
  get running() { return this.child.exitCode === null && this.child.signalCode === null; }
  onLine(line) {
    this.lines.push(line);
    if (this.lines.length > 400) this.lines.splice(0, this.lines.length - 400);
    if (process.env.HAPTICPD_TEST_VERBOSE) console.log(`[${this.name}] ${line}`);
    this.waiters = this.waiters.filter((w) => {
      const m = line.match(w.re);
      if (m) w.resolve(m);
      return !m;
    });
  }
  output() { return this.lines.join('\n'); }
  // Resolves with the match of the first output line (past or future) matching re.
  waitForLine(re, timeoutMs, what) {
    for (const l of this.lines) { const m = l.match(re); if (m) return Promise.resolve(m); }
    return new Promise((resolve, reject) => {
      const w = { re, resolve };
      this.waiters.push(w);
      const t = setTimeout(() => reject(new Error(
          `${this.name}: no output line matching ${re} within ${timeoutMs} ms (${what || ''})`)),
          timeoutMs);
      this.exited.then(({ code, signal }) => {
        clearTimeout(t);
        reject(new Error(`${this.name} exited (code ${code}, signal ${signal}) before printing ` +
                         `a line matching ${re}`));
      });
      const orig = w.resolve;
      w.resolve = (m) => { clearTimeout(t); orig(m); };
    });
  }
  async kill(signal = 'SIGTERM', timeoutMs = 10000) {
    if (!this.running) return this.exited;
    this.child.kill(signal);
    const t = setTimeout(() => { if (this.running) this.child.kill('SIGKILL'); }, timeoutMs);
    const r = await this.exited;
    clearTimeout(t);
    return r;
  }
}

// Runs a hapticpd subcommand to completion; resolves with stdout, rejects
// with its output on a non-zero exit.
export function cli(args, { timeoutMs = 60000 } = {}) {
  return new Promise((resolve, reject) => {
    const child = execFile(config.cli, args, { timeout: timeoutMs, maxBuffer: 64 << 20 },
      (err, stdout, stderr) => {
        children.delete(child);
        if (err) {
          reject(new Error(`hapticpd ${args.join(' ')} failed: ${err.message}\n${stdout}${stderr}`));
        } else {
          resolve(stdout);
        }
      });
    children.add(child);
  });
}

export function freePort(host = '127.0.0.1') {
  return new Promise((resolve, reject) => {
    const srv = net.createServer();
    srv.unref();
    srv.on('error', reject);
    srv.listen(0, host, () => {
      const { port } = srv.address();
      srv.close(() => resolve(port));
    });
  });
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Polls fn() until it returns a truthy value; throws with `what` after timeoutMs.
// (A condition, polled; never a sleep standing in for one.)
export async function until(fn, { timeoutMs = 15000, intervalMs = 50, what = 'condition' } = {}) {
  const end = Date.now() + timeoutMs;
  let last;
  for (;;) {
    try {
      const v = await fn();
      if (v) return v;
    } catch (e) { last = e; }
    if (Date.now() > end) {
      throw new Error(`timed out after ${timeoutMs} ms waiting for ${what}` +
                      (last ? ` (last error: ${last.message})` : ''));
    }
    await sleep(intervalMs);
  }
}

// One HTTP request; resolves {status, headers, body} (never rejects on a status).
export function httpGet(url, { headers = {}, timeoutMs = 5000 } = {}) {
  return new Promise((resolve, reject) => {
    const req = http.get(url, { headers, timeout: timeoutMs }, (res) => {
      const chunks = [];
      res.on('data', (c) => chunks.push(c));
      res.on('end', () => resolve({ status: res.statusCode, headers: res.headers,
                                     body: Buffer.concat(chunks).toString('utf8') }));
    });
    req.on('timeout', () => req.destroy(new Error(`GET ${url}: no answer in ${timeoutMs} ms`)));
    req.on('error', reject);
  });
}

// ---------------------------------------------------------------------------
// hapticpd serve and hapticpd view.

export class Server {
  // A server on 127.0.0.1; port 0 picks a free one (read back from its log).
  static async start({ stateDir = tmpDir('hapticpd-state-'), port = 0, extra = [] } = {}) {
    const s = new Server();
    s.stateDir = stateDir;
    s.proc = new Proc('serve', ['serve', '--listen', `127.0.0.1:${port}`, '--state', stateDir,
                                '--status-interval', '0', ...extra]);
    const m = await s.proc.waitForLine(/listening on [^ ]*:(\d+)/, 20000, 'serve start');
    s.port = Number(m[1]);
    s.address = `127.0.0.1:${s.port}`;
    return s;
  }
  async restart() {
    await this.proc.kill('SIGKILL');
    const s = await Server.start({ stateDir: this.stateDir, port: this.port });
    this.proc = s.proc;
    return this;
  }
  async createScene(id) { await cli(['scene', 'create', id, '--server', this.address]); }
  async inject(scene, id, shape, pose = '0,0,0', extra = []) {
    const what = shape.startsWith('mesh:') ? ['--mesh', shape.slice(5)] : ['--shape', shape];
    await cli(['inject', '--server', this.address, '--scene', scene, '--id', id, ...what,
               '--pose', pose, ...extra]);
  }
  async remove(scene, id) {
    await cli(['remove', '--server', this.address, '--scene', scene, '--body', id]);
  }
  // A simulated device session (not awaited): resolves {code, json} when it ends.
  device(scene, { script = 'press', duration = 4, probe = 'shape:stick', extra = [] } = {}) {
    const p = new Proc('device', ['device', '--server', this.address, '--scene', scene,
                                  '--probe', probe, '--simulated', script,
                                  '--duration', String(duration), '--json', ...extra]);
    p.result = p.exited.then(({ code }) => {
      let json = null;
      for (const l of p.lines) {
        if (l.startsWith('{')) { try { json = JSON.parse(l); } catch { /* not it */ } }
      }
      return { code, json };
    });
    return p;
  }
}

export class Viewer {
  // `hapticpd view` on host:port (a free port when port is 0).
  static async start({ server, scene, host = '127.0.0.1', port = 0, viewerToken, extra = [] }) {
    const v = new Viewer();
    v.server = server;
    v.scene = scene;
    v.host = host;
    v.port = port || await freePort(host === '0.0.0.0' ? '0.0.0.0' : host);
    v.viewerToken = viewerToken;
    v.extra = extra;
    await v.spawn();
    return v;
  }
  get connectHost() { return this.host === '0.0.0.0' ? '127.0.0.1' : this.host; }
  get base() { return `http://${this.connectHost}:${this.port}`; }
  url(pathAndQuery = '/') {
    const u = new URL(pathAndQuery, this.base);
    if (this.viewerToken && !u.searchParams.has('token')) u.searchParams.set('token', this.viewerToken);
    return u.toString();
  }
  async spawn() {
    const args = ['view', '--server', this.server.address, '--scene', this.scene,
                  '--listen', `${this.host}:${this.port}`, ...this.extra];
    if (this.viewerToken) args.push('--viewer-token', this.viewerToken);
    this.proc = new Proc('view', args);
    // Up when /healthz answers (any status: with a viewer token it may want it);
    // fails at once if the process exits first.
    const proc = this.proc;
    let up = false;
    const died = proc.exited.then(({ code, signal }) => {
      if (!up) {
        throw new Error(`hapticpd view exited (code ${code}, signal ${signal}) before answering:\n` +
                        proc.output());
      }
    });
    died.catch(() => {});
    await Promise.race([
      until(async () => (await httpGet(this.url('/healthz'), { timeoutMs: 1000 })).status > 0,
            { timeoutMs: 20000, what: `hapticpd view answering on ${this.base}/healthz` }),
      died]);
    up = true;
  }
  async health() {
    const r = await httpGet(this.url('/healthz'));
    if (r.status !== 200) throw new Error(`/healthz answered ${r.status}: ${r.body.slice(0, 200)}`);
    return JSON.parse(r.body);
  }
  async kill(signal = 'SIGKILL') { return this.proc.kill(signal); }
  async restart() { await this.kill('SIGKILL'); await this.spawn(); }
}

// ---------------------------------------------------------------------------
// The browser.

export const CHROMIUM_ARGS = ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'];

export async function launchBrowser() {
  if (!fs.existsSync(config.chromium)) {
    throw new Error(`chromium-headless-shell not found at ${config.chromium} ` +
                    '(bash docker/install-deps.sh installs it; or set HAPTICPD_CHROMIUM)');
  }
  const { puppeteer } = deps();
  const browser = await puppeteer.launch({
    executablePath: config.chromium,
    headless: 'shell',
    args: [...CHROMIUM_ARGS, '--window-size=1280,800'],
    defaultViewport: { width: 1280, height: 800 },
    userDataDir: tmpDir('hapticpd-chromium-'),
    protocolTimeout: 60000,
  });
  const proc = browser.process();
  if (proc) children.add(proc);
  return browser;
}

// A page with its console and errors kept for failure reports.
export async function openPage(browser, url, { waitReady = true, timeoutMs = 20000 } = {}) {
  const page = await browser.newPage();
  page.logLines = [];
  page.on('console', (m) => page.logLines.push(`console.${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => page.logLines.push(`pageerror: ${e.message}`));
  page.on('requestfailed', (r) => page.logLines.push(`requestfailed: ${r.url()} ${r.failure()?.errorText}`));
  // __count(x): a count from a field that is a number, an array or an object.
  await page.evaluateOnNewDocument(() => {
    window.__count = (x) => (Array.isArray(x) ? x.length :
        (x && typeof x === 'object' ? Object.keys(x).length : Number(x) || 0));
    // The page's WebSockets, newest last, so that a test can hand the page a
    // message in an order the viewer cannot be made to produce on demand
    // (socket.dispatchEvent(new MessageEvent('message', {data}))).
    window.__sockets = [];
    const Native = window.WebSocket;
    window.WebSocket = class extends Native {
      constructor(...args) { super(...args); window.__sockets.push(this); }
    };
  });
  page.response = await page.goto(url, { waitUntil: 'load', timeout: timeoutMs });
  if (waitReady) {
    await waitView(page, () => window.hapticpdView && window.hapticpdView.ready &&
                               document.body.dataset.ready === '1',
                   { timeoutMs, what: 'the page ready (hapticpdView.ready, body data-ready="1")' });
  }
  return page;
}

// ---------------------------------------------------------------------------
// How a test sets up: a server holding one scene, a viewer of it, pages in
// the browser; each kept in ctx for runTest's cleanup and failure report.

// `hapticpd serve` with scene `scene` holding `bodies`, each [id, shape, pose]
// as Server.inject takes them, injected in that order.
export async function serveScene(ctx, scene, bodies) {
  const server = await Server.start();
  ctx.procs.push(server);
  await server.createScene(scene);
  for (const [id, shape, pose] of bodies) await server.inject(scene, id, shape, pose);
  return server;
}

// `hapticpd view` started with Viewer.start's options.
export async function startViewer(ctx, opts) {
  const viewer = await Viewer.start(opts);
  ctx.procs.push(viewer);
  return viewer;
}

// openPage in ctx's browser (launched here when the test has none yet).
export async function openViewer(ctx, url, opts) {
  if (!ctx.browser) ctx.browser = await launchBrowser();
  const page = await openPage(ctx.browser, url, opts);
  ctx.pages.push(page);
  return page;
}

// window.hapticpdView as JSON (without big arrays), for messages.
export async function viewState(page) {
  try {
    return await page.evaluate(() => {
      const v = window.hapticpdView;
      if (!v) return null;
      return JSON.parse(JSON.stringify(v, (k, x) => (Array.isArray(x) && x.length > 20 ?
          `[${x.length} items]` : x)));
    });
  } catch (e) {
    return `(could not read hapticpdView: ${e.message})`;
  }
}

// Waits in the page for fn(arg) to be truthy (polled every 50 ms in the page).
export async function waitView(page, fn, { arg, timeoutMs = 15000, what = 'condition' } = {}) {
  try {
    return await page.waitForFunction(fn, { timeout: timeoutMs, polling: 50 }, arg);
  } catch (e) {
    const st = await viewState(page);
    throw new Error(`page: timed out after ${timeoutMs} ms waiting for ${what}\n` +
                    `  hapticpdView = ${JSON.stringify(st)}\n  (${e.message.split('\n')[0]})`);
  }
}

// A count from a field that may be a number or an array.
export function count(x) {
  if (Array.isArray(x)) return x.length;
  if (x && typeof x === 'object') return Object.keys(x).length;
  return Number(x) || 0;
}

// ---------------------------------------------------------------------------
// The test runner: one test per file, exit 0 (pass), 1 (fail), 77 (skip).

export class Skip extends Error {}

export function check(cond, msg) {
  if (!cond) throw new Error(`check failed: ${msg}`);
}

export async function runTest(name, fn) {
  const t0 = Date.now();
  const ctx = { procs: [], pages: [], browser: null, notes: [] };
  const deadline = setTimeout(() => {
    console.error(`FAIL ${name}: over the test's own deadline of ${config.deadlineS} s`);
    dump(ctx);
    killAllSync();
    process.exit(1);
  }, config.deadlineS * 1000);
  deadline.unref();
  let code = 0;
  try {
    await fn(ctx);
    console.log(`PASS ${name} (${((Date.now() - t0) / 1000).toFixed(1)} s)`);
  } catch (e) {
    if (e instanceof Skip) {
      console.log(`SKIP ${name}: ${e.message}`);
      code = SKIP;
    } else {
      console.error(`FAIL ${name} after ${((Date.now() - t0) / 1000).toFixed(1)} s: ${e.stack || e}`);
      await dumpPages(ctx);
      dump(ctx);
      code = 1;
    }
  }
  clearTimeout(deadline);
  if (ctx.browser) await ctx.browser.close().catch(() => {});
  killAllSync();
  process.exit(code);
}

function dump(ctx) {
  for (const p of ctx.procs) {
    const proc = p.proc || p;
    if (!proc.lines) continue;
    console.error(`--- ${proc.name} (${proc.args.join(' ')}): last output ---`);
    console.error(proc.lines.slice(-40).join('\n'));
  }
}

async function dumpPages(ctx) {
  for (const page of ctx.pages) {
    console.error('--- page console (last 30) ---');
    console.error((page.logLines || []).slice(-30).join('\n'));
    console.error(`--- hapticpdView: ${JSON.stringify(await viewState(page))}`);
  }
}

// ---------------------------------------------------------------------------
// TCP queues from /proc/net/tcp (IPv4) and tcp6: which sockets on `port`
// hold unsent (tx) or unread (rx) bytes. Used to prove a stalled reader
// really is stalled (the viewer's send queue to it fills).
export function tcpSockets(port) {
  const out = [];
  for (const f of ['/proc/net/tcp', '/proc/net/tcp6']) {
    let text;
    try { text = fs.readFileSync(f, 'utf8'); } catch { continue; }
    for (const line of text.split('\n').slice(1)) {
      const cols = line.trim().split(/\s+/);
      if (cols.length < 5) continue;
      const lport = parseInt(cols[1].split(':')[1], 16);
      const rport = parseInt(cols[2].split(':')[1], 16);
      const [tx, rx] = cols[4].split(':').map((h) => parseInt(h, 16));
      if (lport === port || rport === port) {
        out.push({ localPort: lport, remotePort: rport, state: cols[3], txQueue: tx, rxQueue: rx });
      }
    }
  }
  return out;
}
