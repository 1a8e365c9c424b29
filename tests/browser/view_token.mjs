// (e) The viewer token off loopback: `hapticpd view --listen 0.0.0.0:PORT
// --viewer-token V`, reached through 127.0.0.1. The page, its WebSocket and
// a mesh request without a token, or with a wrong one (query or Bearer), are
// refused with 401; with the right one they are served and the page becomes
// ready and shows the scene.
import net from 'node:net';
import { runTest, serveScene, startViewer, launchBrowser, openPage, openViewer, waitView, check,
         httpGet, viewState } from './lib/harness.mjs';

const TOKEN = 'v1ewer-t0ken-for-the-test';

// A WebSocket upgrade by hand; resolves the HTTP status line's code.
function wsUpgradeStatus(port, pathAndQuery, headers = {}) {
  return new Promise((resolve, reject) => {
    const sock = net.connect(port, '127.0.0.1', () => {
      const extra = Object.entries(headers).map(([k, v]) => `${k}: ${v}\r\n`).join('');
      sock.write(`GET ${pathAndQuery} HTTP/1.1\r\nHost: 127.0.0.1:${port}\r\n` +
                 'Upgrade: websocket\r\nConnection: Upgrade\r\n' +
                 'Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n' +
                 `${extra}\r\n`);
    });
    let buf = '';
    sock.setTimeout(5000, () => { sock.destroy(); reject(new Error(`no answer to the upgrade of ${pathAndQuery}`)); });
    sock.on('data', (d) => {
      buf += d.toString('latin1');
      const m = buf.match(/^HTTP\/1\.1 (\d{3})/);
      if (m) { sock.destroy(); resolve(Number(m[1])); }
    });
    sock.on('error', reject);
    sock.on('close', () => reject(new Error(`connection closed with no status (${JSON.stringify(buf.slice(0, 100))})`)));
  });
}

runTest('view_token', async (ctx) => {
  const server = await serveScene(ctx, 'guarded', [['thing', 'box:0.02,0.02,0.02', '0,0,0']]);
  const viewer = await startViewer(ctx, { server, scene: 'guarded', host: '0.0.0.0',
                                          viewerToken: TOKEN });
  const base = viewer.base;  // http://127.0.0.1:PORT
  const port = viewer.port;

  // The page, without and with a token.
  const cases = [
    ['/ without a token', '/', {}, 401],
    ['/ with a wrong ?token', '/?token=wrong', {}, 401],
    ['/ with a wrong Bearer', '/', { Authorization: 'Bearer wrong' }, 401],
    ['/ with an empty ?token', '/?token=', {}, 401],
    ['/ with the token as a prefix of the right one', `/?token=${TOKEN.slice(0, -1)}`, {}, 401],
    ['/ with the right ?token', `/?token=${TOKEN}`, {}, 200],
    ['/ with the right Bearer', '/', { Authorization: `Bearer ${TOKEN}` }, 200],
  ];
  for (const [what, p, headers, want] of cases) {
    const r = await httpGet(base + p, { headers });
    check(r.status === want, `GET ${what}: ${r.status}, want ${want}`);
  }

  // The WebSocket (found from the page: the first ws path it names, else /ws).
  const html = (await httpGet(`${base}/?token=${TOKEN}`)).body;
  const wsPath = ((html.match(/["'`](\/ws[a-zA-Z0-9_/-]*)/) || [])[1]) || '/ws';
  check(await wsUpgradeStatus(port, wsPath) === 401, `WebSocket ${wsPath} without a token: 401`);
  check(await wsUpgradeStatus(port, `${wsPath}?token=wrong`) === 401,
        `WebSocket ${wsPath} with a wrong token: 401`);
  check(await wsUpgradeStatus(port, wsPath, { Authorization: 'Bearer wrong' }) === 401,
        `WebSocket ${wsPath} with a wrong Bearer: 401`);
  check(await wsUpgradeStatus(port, `${wsPath}?token=${TOKEN}`) === 101,
        `WebSocket ${wsPath} with the right token: 101`);

  // In the browser: no token, refused; the right token, the page works.
  ctx.browser = await launchBrowser();
  const bad = await openPage(ctx.browser, `${base}/`, { waitReady: false });
  check(bad.response.status() === 401, `the browser without a token: ${bad.response.status()}, want 401`);
  check(!(await bad.evaluate(() => !!window.hapticpdView)), 'no viewer state on the refused page');
  await bad.close();

  const page = await openViewer(ctx, `${base}/?token=${TOKEN}`);
  check(page.response.status() === 200, 'the page with the right token: 200');
  await waitView(page, () => window.hapticpdView.connected && __count(window.hapticpdView.bodies) === 1,
                 { what: 'the page with the token connected, its body shown (mesh fetched with the token)' });

  // Every request the page made (page, scripts, WebSocket, meshes) was
  // answered: none refused.
  const refused = [];
  page.on('response', (r) => { if (r.status() === 401) refused.push(r.url()); });
  await page.reload({ waitUntil: 'load' });
  await waitView(page, () => window.hapticpdView.ready && __count(window.hapticpdView.bodies) === 1,
                 { what: 'the page ready again after a reload' });
  check(refused.length === 0, `no request of the page refused: ${refused.join(', ')}`);

  // The mesh URLs the page used, without the token: refused.
  const meshUrls = await page.evaluate(() => performance.getEntriesByType('resource')
      .map((e) => e.name).filter((u) => /mesh/i.test(u)));
  console.log(`mesh requests: ${meshUrls.join(', ') || '(none found by name)'}`);
  for (const u of meshUrls) {
    const stripped = new URL(u);
    stripped.searchParams.delete('token');
    const r = await httpGet(stripped.toString());
    check(r.status === 401, `mesh ${stripped.pathname} without the token: ${r.status}, want 401`);
  }
  console.log(`view: ${JSON.stringify(await viewState(page))}`);
});
