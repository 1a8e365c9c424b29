// (c) Recovery without a reload: the viewer process is killed and started
// again on the same port (the page reconnects its WebSocket: wsConnects
// grows, the bodies are shown again); then the server is killed and started
// again on the same port and state directory (the viewer reconnects:
// serverConnected false, then true again, the bodies shown again, a body
// injected after the restart appears). The page is never reloaded: a marker
// set on window at the start is still there at the end.
import { runTest, serveScene, startViewer, openViewer, waitView, check, until } from './lib/harness.mjs';

runTest('view_recover', async (ctx) => {
  const server = await serveScene(ctx, 'again', [['one', 'box:0.05,0.05,0.01', '0,0,-0.01'],
                                                  ['two', 'sphere:0.02', '0,0,0.02']]);
  const viewer = await startViewer(ctx, { server, scene: 'again' });
  const page = await openViewer(ctx, viewer.url('/'));
  await page.evaluate(() => { window.__notReloaded = 'yes'; });

  const twoBodies = () => {
    const v = window.hapticpdView;
    return v.connected && v.serverConnected && __count(v.bodies) === 2 && __count(v.bodyIds) === 2;
  };
  await waitView(page, twoBodies, { what: '2 bodies shown' });
  const ws0 = await page.evaluate(() => window.hapticpdView.wsConnects);
  check(ws0 >= 1, `wsConnects ${ws0} >= 1 after the first connect`);

  // 1. The viewer process dies (SIGKILL: no goodbye on the socket).
  await viewer.kill('SIGKILL');
  await waitView(page, () => !window.hapticpdView.connected,
                 { what: 'the page noticing the viewer is gone (connected false)' });
  await viewer.spawn();  // same port
  await waitView(page, (w0) => window.hapticpdView.wsConnects > w0, { arg: ws0, timeoutMs: 20000,
                 what: 'the page reconnecting to the restarted viewer (wsConnects grows)' });
  await waitView(page, twoBodies, { timeoutMs: 20000,
                 what: '2 bodies shown again after the viewer restart' });
  const ws1 = await page.evaluate(() => window.hapticpdView.wsConnects);

  // 2. The server dies; the viewer stays.
  await server.proc.kill('SIGKILL');
  await waitView(page, () => window.hapticpdView.serverConnected === false, { timeoutMs: 20000,
                 what: 'the page saying the server is gone (serverConnected false)' });
  await until(async () => (await viewer.health()).server_connected === false,
              { what: '/healthz server_connected false' });
  await server.restart();  // same port, same state directory: the scene is still there
  await waitView(page, twoBodies, { timeoutMs: 30000,
                 what: 'the viewer reconnecting to the restarted server, 2 bodies shown again' });
  await until(async () => (await viewer.health()).server_connected === true,
              { what: '/healthz server_connected true' });

  // Live again: a change after the restart is shown.
  await server.inject('again', 'three', 'box:0.01,0.01,0.01', '0.03,0,0.02');
  await waitView(page, () => __count(window.hapticpdView.bodies) === 3 &&
                             window.hapticpdView.bodyIds.includes('three'),
                 { what: 'a body injected after the server restart shown' });

  check(await page.evaluate(() => window.__notReloaded) === 'yes', 'the page was not reloaded');
  const ws2 = await page.evaluate(() => window.hapticpdView.wsConnects);
  check(ws2 >= ws1, `wsConnects ${ws2} did not go back`);
  console.log(`wsConnects: ${ws0} -> ${ws1} (viewer restart) -> ${ws2} (server restart)`);
});
