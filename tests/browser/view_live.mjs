// (a) A page against a running server with a simulated device session
// pressing a stick into a box: the page shows every body, the probe moves,
// contacts appear while pressing, the force plot has samples. Writes a
// screenshot (HAPTICPD_SCREENSHOT, build/viewer-screenshot.png).
import fs from 'node:fs';
import path from 'node:path';
import { runTest, Server, Viewer, launchBrowser, openPage, waitView, check, count, config,
         viewState } from './lib/harness.mjs';

runTest('view_live', async (ctx) => {
  const server = await Server.start();
  ctx.procs.push(server);
  await server.createScene('live');
  await server.inject('live', 'table', 'box:0.15,0.15,0.01', '0,0,-0.01');
  await server.inject('live', 'block', 'box:0.02,0.02,0.02', '0,0,0.02');
  await server.inject('live', 'ball', 'sphere:0.015', '0.07,0.05,0.015');

  const viewer = await Viewer.start({ server, scene: 'live' });
  ctx.procs.push(viewer);
  ctx.browser = await launchBrowser();
  const page = await openPage(ctx.browser, viewer.url('/'));
  ctx.pages.push(page);

  await waitView(page, () => {
    const v = window.hapticpdView;
    return v.connected && v.serverConnected && __count(v.bodies) === 3 && __count(v.bodyIds) === 3;
  }, { what: '3 bodies shown, connected to the viewer and the viewer to the server' });
  const ids = await page.evaluate(() => [...window.hapticpdView.bodyIds].sort());
  check(JSON.stringify(ids) === JSON.stringify(['ball', 'block', 'table']),
        `bodyIds ${JSON.stringify(ids)} are the scene's bodies`);
  const h = await viewer.health();
  check(h.server_connected === true && h.scene_id === 'live' && h.browsers >= 1,
        `/healthz ${JSON.stringify(h)}: server_connected, scene_id live, >= 1 browser`);

  // The device session: the stick starts above the scene, centred over the
  // block, presses 20 mm down and comes back over 6 s.
  const device = server.device('live', { script: 'press', duration: 6 });
  ctx.procs.push(device);

  const first = await waitView(page, () => {
    const v = window.hapticpdView;
    const ids = Object.keys(v.probes || {});
    return ids.length === 1 && __count(v.sessions) >= 1 && v.probes[ids[0]].position;
  }, { timeoutMs: 15000, what: "the device session's probe shown" }).then((h) => h.jsonValue());
  check(first.length === 3 && first.every(Number.isFinite), `probe position ${first} is 3 numbers`);

  await waitView(page, (p0) => {
    const v = window.hapticpdView;
    const pr = Object.values(v.probes)[0];
    if (!pr) return false;
    const d = Math.hypot(pr.position[0] - p0[0], pr.position[1] - p0[1], pr.position[2] - p0[2]);
    return d > 0.002;
  }, { arg: first, what: 'the probe moved more than 2 mm from where it was first shown' });

  await waitView(page, () => {
    const v = window.hapticpdView;
    const pr = Object.values(v.probes)[0];
    return __count(v.contacts) > 0 && pr && __count(pr.rows) > 0 && pr.depth > 0;
  }, { timeoutMs: 15000, what: 'contacts shown while the stick presses into the block' });

  await waitView(page, () => __count(window.hapticpdView.plotSamples) > 100,
                 { what: 'the force plot holding more than 100 samples' });
  const frames0 = await page.evaluate(() => window.hapticpdView.framesRendered);
  await waitView(page, (f0) => window.hapticpdView.framesRendered > f0 + 5,
                 { arg: frames0, what: 'the page drawing frames' });

  // While still in contact: the picture for the README.
  fs.mkdirSync(path.dirname(config.screenshot), { recursive: true });
  await page.screenshot({ path: config.screenshot });
  const png = fs.readFileSync(config.screenshot);
  check(png.length > 10000 && png.readUInt32BE(16) === 1280 && png.readUInt32BE(20) === 800,
        `screenshot ${config.screenshot} is a 1280x800 PNG (${png.length} bytes)`);
  console.log(`screenshot: ${config.screenshot}`);

  const { code, json } = await device.result;
  check(code === 0 && json, `the device session ended cleanly (exit ${code})`);
  check(json.max_depth > 0, `the device felt the block (max_depth ${json.max_depth})`);

  // The session's end is shown too.
  await waitView(page, () => Object.keys(window.hapticpdView.probes).length === 0 &&
                             __count(window.hapticpdView.sessions) === 0,
                 { what: 'the ended session removed from the page' });
  console.log(`final view: ${JSON.stringify(await viewState(page))}`);
  check(count((await viewState(page)).bodyIds) === 3, 'still 3 bodies');
});
