// (d) A browser that stops reading does not change a device session's
// update rate (labels `browser` and `timing`, run alone). In one run, 1 kHz
// simulated device sessions (a stick pressing into a box, 3 s each)
// alternate:
//   A: the viewer watching the scene, no browser;
//   B: the same with a page opened, shown ready, then paused by the debugger
//      (CDP Debugger.pause: it runs no JavaScript, its WebSocket is not
//      read), and a WebSocket client that completed the upgrade and never
//      reads a byte (tests/browser/lib/stalled_ws_client.py, a 4 KiB receive
//      buffer);
// A, B, A, B. The checks: mean rate(B) / mean rate(A) >= 0.9 (a generous
// margin for a shared 2-core machine; bench_view's goal is 2 %); the stall
// was real (the viewer's send queue to the never-reading client held at
// least 8 KiB, read from /proc/net/tcp); the resumed page is live again.
// A paused page's bytes keep being taken by Chromium's network process (it
// buffers megabytes before it pushes back), so the never-reading client is
// what fills the viewer's queue.
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { runTest, serveScene, startViewer, Proc, launchBrowser, openViewer, waitView, check, until,
         tcpSockets, viewState } from './lib/harness.mjs';

const RUN_S = 3;
const MIN_RATIO = Number(process.env.HAPTICPD_STALL_MIN_RATIO || 0.9);
const MIN_STALLED_BYTES = 8192;
const here = path.dirname(fileURLToPath(import.meta.url));

runTest('view_stalled', async (ctx) => {
  const server = await serveScene(ctx, 'stall', [['block', 'box:0.03,0.03,0.02', '0,0,0']]);
  const viewer = await startViewer(ctx, { server, scene: 'stall' });
  // Running from the start, so that sessions A and B differ only in the page and the client.
  ctx.browser = await launchBrowser();

  const rates = { A: [], B: [] };
  const session = async (label) => {
    const dev = server.device('stall', { script: 'press', duration: RUN_S });
    ctx.procs.push(dev);
    const { code, json } = await dev.result;
    check(code === 0 && json, `device session ${label} ended cleanly (exit ${code})`);
    const rate = json.updates / json.elapsed_s;
    rates[label].push(rate);
    console.log(`${label}: ${json.updates} updates in ${json.elapsed_s.toFixed(3)} s = ${rate.toFixed(1)}/s ` +
                `(loop ${json.loop_hz.toFixed(1)} Hz, rtt p99 ${json.rtt_p99_us.toFixed(0)} us, ` +
                `max depth ${(json.max_depth * 1e3).toFixed(1)} mm)`);
    return json;
  };

  let stalledTx = 0;
  for (let round = 0; round < 2; round++) {
    await session('A');

    // B: a page, ready and showing the block, then paused; a client that never reads.
    const page = await openViewer(ctx, viewer.url('/'));
    await waitView(page, () => window.hapticpdView.connected && __count(window.hapticpdView.bodies) === 1,
                   { what: 'the page showing the block' });
    const cdp = await page.createCDPSession();
    await cdp.send('Debugger.enable');
    const paused = new Promise((r) => cdp.once('Debugger.paused', r));
    await cdp.send('Debugger.pause');
    await Promise.race([paused, new Promise((_, rej) => setTimeout(
        () => rej(new Error('the page did not pause within 10 s')), 10000))]);
    const wsPath = new URL(viewer.url('/ws')).pathname + new URL(viewer.url('/ws')).search;
    const raw = new Proc('stalled-client', [path.join(here, 'lib', 'stalled_ws_client.py'),
                                            String(viewer.port), wsPath], { command: '/usr/bin/python3' });
    ctx.procs.push(raw);
    const rawPort = Number((await raw.waitForLine(/^upgraded (\d+)/, 10000, 'the upgrade'))[1]);

    let roundTx = 0;
    const watching = { on: true };
    const watcher = (async () => {
      while (watching.on) {
        for (const s of tcpSockets(viewer.port)) {
          if (s.localPort === viewer.port && s.remotePort === rawPort) roundTx = Math.max(roundTx, s.txQueue);
        }
        await new Promise((r) => setTimeout(r, 20));
      }
    })();
    await session('B');
    watching.on = false;
    await watcher;
    stalledTx = Math.max(stalledTx, roundTx);
    console.log(`  the viewer's send queue to the never-reading client reached ${roundTx} bytes`);
    await raw.kill('SIGKILL');

    await cdp.send('Debugger.resume');
    await cdp.detach();
    const f0 = await page.evaluate(() => window.hapticpdView.framesRendered);
    await waitView(page, (f) => window.hapticpdView.connected && window.hapticpdView.framesRendered > f + 3,
                   { arg: f0, timeoutMs: 20000, what: 'the page live again after being resumed' });
    if (round === 1) console.log(`page after the stall: ${JSON.stringify(await viewState(page))}`);
    await page.close();
    ctx.pages.pop();
  }

  const mean = (a) => a.reduce((s, x) => s + x, 0) / a.length;
  const ratio = mean(rates.B) / mean(rates.A);
  console.log(`update rate: no browser ${mean(rates.A).toFixed(1)}/s, a paused page and a never-reading ` +
              `client ${mean(rates.B).toFixed(1)}/s: ratio ${ratio.toFixed(3)} (must be >= ${MIN_RATIO})`);
  check(stalledTx >= MIN_STALLED_BYTES, `the stall was real: the viewer's send queue to the ` +
        `never-reading client reached ${stalledTx} bytes (>= ${MIN_STALLED_BYTES})`);
  check(Math.min(...rates.A) > 500, `the session runs near 1 kHz without a browser ` +
                                    `(${rates.A.map((r) => r.toFixed(0)).join(', ')}/s)`);
  check(ratio >= MIN_RATIO, `update-rate ratio ${ratio.toFixed(3)} >= ${MIN_RATIO}`);
});
