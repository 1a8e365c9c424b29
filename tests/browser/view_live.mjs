// (a) A page against a running server with a simulated device session
// pressing a stick into a box: the page shows every body, the probe moves,
// contacts appear while pressing, the force plot has samples, no shader
// program is built after load, and the session's end removes it for good
// (a late telemetry batch does not bring it back). Writes a
// screenshot (HAPTICPD_SCREENSHOT, build/viewer-screenshot.png).
import fs from 'node:fs';
import path from 'node:path';
import { runTest, serveScene, startViewer, openViewer, waitView, check, count, config,
         viewState } from './lib/harness.mjs';

runTest('view_live', async (ctx) => {
  const server = await serveScene(ctx, 'live', [['table', 'box:0.15,0.15,0.01', '0,0,-0.01'],
                                                 ['block', 'box:0.02,0.02,0.02', '0,0,0.02'],
                                                 ['ball', 'sphere:0.015', '0.07,0.05,0.015']]);
  const viewer = await startViewer(ctx, { server, scene: 'live' });
  const page = await openViewer(ctx, viewer.url('/'));

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

  // The page built every shader program it needs at load: a session's
  // probe, ghost, arrows and contacts, when they come, build none (in
  // software WebGL a build froze the page for about a second).
  const programs0 = await page.evaluate(() => window.hapticpdView.programs);
  check(programs0 > 0, `the page reports the programs it built (${programs0})`);

  // What the page shows, recorded in the page every 10 ms from now on, so
  // that nothing transient (the contact lasts about a second) is missed
  // between two polls of this process.
  await page.evaluate(() => {
    const r = window.__rec = { probes: 0, sessions: 0, lo: null, hi: null, contacts: 0, rows: 0,
                               depth: 0, plot: 0, programs: 0, ids: [] };
    setInterval(() => {
      const v = window.hapticpdView;
      const ps = Object.values(v.probes || {});
      r.probes = Math.max(r.probes, ps.length);
      for (const id of Object.keys(v.probes || {})) if (!r.ids.includes(id)) r.ids.push(id);
      r.sessions = Math.max(r.sessions, __count(v.sessions));
      for (const p of ps) {
        if (!Array.isArray(p.position) || p.position.length !== 3 || !p.position.every(Number.isFinite)) continue;
        r.lo = r.lo ? r.lo.map((x, i) => Math.min(x, p.position[i])) : p.position.slice();
        r.hi = r.hi ? r.hi.map((x, i) => Math.max(x, p.position[i])) : p.position.slice();
        r.rows = Math.max(r.rows, __count(p.rows));
        r.depth = Math.max(r.depth, Number(p.depth) || 0);
      }
      r.contacts = Math.max(r.contacts, __count(v.contacts));
      r.plot = Math.max(r.plot, __count(v.plotSamples));
      r.programs = Math.max(r.programs, v.programs);
    }, 10);
  });

  // The device session: the stick starts above the scene, centred over the
  // block, presses 20 mm down and comes back over 9 s (in the block for
  // about 6 s: time for the screenshot on a loaded machine).
  const t0 = Date.now();
  const stamp = (what) => console.log(`${((Date.now() - t0) / 1000).toFixed(1)} s: ${what}`);
  const device = server.device('live', { script: 'press', duration: 9 });
  ctx.procs.push(device);

  await waitView(page, () => window.__rec.probes === 1 && window.__rec.sessions >= 1,
                 { what: "the device session's probe shown" });
  stamp('probe shown');
  await waitView(page, () => {
    const r = window.__rec;
    return r.lo && Math.hypot(r.hi[0] - r.lo[0], r.hi[1] - r.lo[1], r.hi[2] - r.lo[2]) > 0.002;
  }, { what: 'the probe shown moving more than 2 mm' });
  stamp('probe moved');
  // The picture for the README while the stick is in the block (not fatal if missed).
  await waitView(page, () => __count(window.hapticpdView.contacts) > 0,
                 { timeoutMs: 10000, what: 'a contact on screen for the screenshot' })
    .catch((e) => console.log(`note: ${e.message.split('\n')[0]}`));
  fs.mkdirSync(path.dirname(config.screenshot), { recursive: true });
  await page.screenshot({ path: config.screenshot });
  stamp('screenshot taken');
  const png = fs.readFileSync(config.screenshot);
  check(png.length > 10000 && png.readUInt32BE(16) === 1280 && png.readUInt32BE(20) === 800,
        `screenshot ${config.screenshot} is a 1280x800 PNG (${png.length} bytes)`);
  console.log(`screenshot: ${config.screenshot}`);

  // While pressing: contacts (rows, depth) shown, and the plot has data.
  await waitView(page, () => {
    const r = window.__rec;
    return r.contacts > 0 && r.rows > 0 && r.depth > 0;
  }, { timeoutMs: 15000, what: 'contacts shown while the stick pressed into the block (recorded maxima)' });
  await waitView(page, () => window.__rec.plot > 100,
                 { what: 'the force plot holding more than 100 samples' });
  const frames0 = await page.evaluate(() => window.hapticpdView.framesRendered);
  await waitView(page, (f0) => window.hapticpdView.framesRendered > f0 + 5,
                 { arg: frames0, what: 'the page drawing frames' });
  const rec = await page.evaluate(() => window.__rec);
  console.log(`recorded: ${JSON.stringify(rec)}`);
  check(rec.programs === programs0,
        `no shader program built after load: ${programs0} at load, ${rec.programs} with the session`);

  const { code, json } = await device.result;
  check(code === 0 && json, `the device session ended cleanly (exit ${code})`);
  check(json.max_depth > 0, `the device felt the block (max_depth ${json.max_depth})`);

  // The session's end is shown too.
  await waitView(page, () => Object.keys(window.hapticpdView.probes).length === 0 &&
                             __count(window.hapticpdView.sessions) === 0,
                 { what: 'the ended session removed from the page' });
  // The session's last telemetry batch arriving after its removal (the
  // viewer sends announcements before queued telemetry) must not bring the
  // ended session back.
  const ended = rec.ids[0];
  await page.evaluate((id) => {
    const ws = window.__sockets[window.__sockets.length - 1];
    const batch = { type: 'telemetry', sessions: [{ id, revision: 1, update_rate_hz: 1000,
                    device: { seq: 1, servo_rate_hz: 1000 }, commanded: [], server: [] }] };
    ws.dispatchEvent(new MessageEvent('message', { data: JSON.stringify(batch) }));
  }, ended);
  const late = await page.evaluate(() => __count(window.hapticpdView.sessions));
  check(late === 0, `a late telemetry batch of the ended session '${ended}' leaves no session shown (${late})`);
  console.log(`final view: ${JSON.stringify(await viewState(page))}`);
  check(count((await viewState(page)).bodyIds) === 3, 'still 3 bodies');
});
