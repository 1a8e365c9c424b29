// (d) A browser that stops reading does not change a device session's
// update rate (label `timing`, release preset only). In one run, 1 kHz
// simulated device sessions (press into a box, 3 s each) alternate:
//   A: the viewer watching the scene, no browser;
//   B: the same with a page whose JavaScript is paused by the debugger
//      (CDP Debugger.pause: its WebSocket is not read) and a raw WebSocket
//      client that completed the handshake and never reads a byte;
// A, B, A, B. The check: mean rate(B) / mean rate(A) >= 0.9 (a generous
// margin for a shared 2-core machine; the benchmark's goal is 2 %), and the
// stall was real: the viewer's send queue to the raw client is non-empty
// and the page reported Debugger.paused. After the stall the page
// is resumed and must be live again (reconnected or caught up).
import net from 'node:net';
import { runTest, Server, Viewer, launchBrowser, openPage, waitView, check, until, tcpSockets,
         viewState } from './lib/harness.mjs';

const RUN_S = 3;
const MIN_RATIO = Number(process.env.HAPTICPD_STALL_MIN_RATIO || 0.9);

// A WebSocket client that completes the upgrade and then never reads.
function rawStalledClient(port, wsPath, token) {
  return new Promise((resolve, reject) => {
    const q = token ? `?token=${encodeURIComponent(token)}` : '';
    const sock = net.connect(port, '127.0.0.1', () => {
      sock.write(`GET ${wsPath}${q} HTTP/1.1\r\nHost: 127.0.0.1:${port}\r\n` +
                 'Upgrade: websocket\r\nConnection: Upgrade\r\n' +
                 'Sec-WebSocket-Key: c3RhbGxlZCBjbGllbnQgISE=\r\nSec-WebSocket-Version: 13\r\n\r\n');
    });
    let buf = '';
    const onData = (d) => {
      buf += d.toString('latin1');
      if (buf.includes('\r\n\r\n')) {
        sock.off('data', onData);
        if (!/^HTTP\/1\.1 101/.test(buf)) { reject(new Error(`upgrade refused: ${buf.split('\r\n')[0]}`)); return; }
        sock.pause();  // never read again: the kernel's receive buffer fills, then the viewer's send queue
        resolve(sock);
      }
    };
    sock.on('data', onData);
    sock.on('error', (e) => reject(e));
  });
}

runTest('view_stalled', async (ctx) => {
  const server = await Server.start();
  ctx.procs.push(server);
  await server.createScene('stall');
  await server.inject('stall', 'block', 'box:0.03,0.03,0.02', '0,0,0');
  const viewer = await Viewer.start({ server, scene: 'stall' });
  ctx.procs.push(viewer);

  ctx.browser = await launchBrowser();
  const page = await openPage(ctx.browser, viewer.url('/'));
  ctx.pages.push(page);
  await waitView(page, () => window.hapticpdView.connected && __count(window.hapticpdView.bodies) === 1,
                 { what: 'the page showing the block' });
  const html = await page.content();
  const wsPath = ((html.match(/["'`](\/ws[a-zA-Z0-9_/-]*)/) || [])[1]) || '/ws';
  const cdp = await page.createCDPSession();
  await cdp.send('Debugger.enable');

  const rates = { A: [], B: [] };
  const session = async (label) => {
    const dev = server.device('stall', { script: 'press', duration: RUN_S });
    ctx.procs.push(dev);
    const { code, json } = await dev.result;
    check(code === 0 && json, `device session ${label} ended cleanly (exit ${code})`);
    const rate = json.updates / json.elapsed_s;
    rates[label].push(rate);
    console.log(`${label}: ${json.updates} updates in ${json.elapsed_s.toFixed(3)} s = ${rate.toFixed(1)}/s ` +
                `(loop ${json.loop_hz.toFixed(1)} Hz, rtt p99 ${json.rtt_p99_us.toFixed(0)} us)`);
    return json;
  };

  let stalledTx = 0;
  let pageTx = 0;  // the most unsent bytes towards the other sockets (the paused page's), reported
  for (let round = 0; round < 2; round++) {
    // A: the page open and reading, no stalled reader.
    await session('A');

    // B: pause the page, add a raw client that never reads.
    const paused = new Promise((r) => cdp.once('Debugger.paused', r));
    await cdp.send('Debugger.pause');
    await Promise.race([paused, new Promise((_, rej) => setTimeout(
        () => rej(new Error('the page did not pause within 10 s (no JavaScript running?)')), 10000))]);
    const raw = await rawStalledClient(viewer.port, wsPath, viewer.viewerToken);
    const dev = session('B');
    // While the session runs: the viewer's queue towards the raw client fills.
    await until(() => {
      const q = tcpSockets(viewer.port).filter((s) => s.localPort === viewer.port && s.remotePort === raw.localPort);
      stalledTx = Math.max(stalledTx, ...q.map((s) => s.txQueue), 0);
      const others = tcpSockets(viewer.port).filter((s) => s.localPort === viewer.port && s.remotePort !== raw.localPort);
      pageTx = Math.max(pageTx, ...others.map((s) => s.txQueue), 0);
      return stalledTx > 0;
    }, { timeoutMs: (RUN_S + 5) * 1000, what: "the viewer's send queue to the never-reading client growing" })
      .catch((e) => { console.error(`warning: ${e.message}`); });
    await dev;
    raw.destroy();
    await cdp.send('Debugger.resume');
    // The page comes back: drawing frames and connected.
    const f0 = await page.evaluate(() => window.hapticpdView.framesRendered);
    await waitView(page, (f) => window.hapticpdView.connected && window.hapticpdView.framesRendered > f + 3,
                   { arg: f0, timeoutMs: 20000, what: 'the page live again after being resumed' });
  }
  check(stalledTx > 0, `the stall was real: the viewer's send queue to the never-reading client reached ` +
                       `${stalledTx} bytes`);

  console.log(`most unsent bytes from the viewer: to the raw client ${stalledTx}, to the paused page ${pageTx}`);
  const mean = (a) => a.reduce((s, x) => s + x, 0) / a.length;
  const ratio = mean(rates.B) / mean(rates.A);
  console.log(`update rate: without a stalled browser ${mean(rates.A).toFixed(1)}/s, with ` +
              `${mean(rates.B).toFixed(1)}/s: ratio ${ratio.toFixed(3)} (must be >= ${MIN_RATIO})`);
  console.log(`view: ${JSON.stringify(await viewState(page))}`);
  check(ratio >= MIN_RATIO, `update-rate ratio ${ratio.toFixed(3)} >= ${MIN_RATIO}`);
  check(Math.min(...rates.A) > 500, `the session runs near 1 kHz without a stalled browser ` +
                                    `(${rates.A.map((r) => r.toFixed(0)).join(', ')}/s)`);
});
