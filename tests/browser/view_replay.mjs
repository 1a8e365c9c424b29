// (f) Replay: a session recorded by `hapticpd device --record` plays in the
// same page (`hapticpd view --replay FILE`): the scene's bodies, the probe
// moving as recorded, its contacts while it pressed, the plot of the
// commanded force, and the page saying that it shows a replay.
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { runTest, serveScene, startViewer, openViewer, waitView, check } from './lib/harness.mjs';

runTest('view_replay', async (ctx) => {
  const server = await serveScene(ctx, 'rec', [['table', 'box:0.15,0.15,0.01', '0,0,-0.01'],
                                                ['block', 'box:0.02,0.02,0.02', '0,0,0.02']]);

  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'hapticpd-replay-'));
  const file = path.join(dir, 'press.csv');
  const device = server.device('rec', { script: 'press', duration: 4, extra: ['--record', file] });
  ctx.procs.push(device);
  const { code, json } = await device.result;
  check(code === 0 && json && json.max_depth > 0,
        `the recorded session ended cleanly and felt the block (exit ${code})`);
  const lines = fs.readFileSync(file, 'utf8').split('\n');
  check(lines[0] === '# hapticpd device trajectory v2', `a version 2 recording (${lines[0]})`);

  // The scene is fetched from the server the recording names; --loop so
  // that the contact comes round again whenever the page looks.
  const viewer = await startViewer(ctx, { server, scene: 'rec', extra: ['--replay', file, '--loop'] });
  const h = await viewer.health();
  check(h.source === `replay of ${file}` && h.bodies === 2, `/healthz ${JSON.stringify(h)}: a replay, 2 bodies`);
  const page = await openViewer(ctx, viewer.url('/'));
  await waitView(page, () => {
    const v = window.hapticpdView;
    return v.connected && __count(v.bodies) === 2 && v.source.startsWith('replay of ');
  }, { what: "the recording's 2 bodies shown, the page saying it is a replay" });

  await page.evaluate(() => {
    const r = window.__rec = { probes: 0, lo: null, hi: null, rows: 0, depth: 0, plot: 0 };
    setInterval(() => {
      const v = window.hapticpdView;
      for (const p of Object.values(v.probes || {})) {
        r.probes = 1;
        if (!Array.isArray(p.position) || !p.position.every(Number.isFinite)) continue;
        r.lo = r.lo ? r.lo.map((x, i) => Math.min(x, p.position[i])) : p.position.slice();
        r.hi = r.hi ? r.hi.map((x, i) => Math.max(x, p.position[i])) : p.position.slice();
        r.rows = Math.max(r.rows, __count(p.rows));
        r.depth = Math.max(r.depth, Number(p.depth) || 0);
      }
      r.plot = Math.max(r.plot, __count(v.plotSamples));
    }, 10);
  });
  await waitView(page, () => {
    const r = window.__rec;
    return r.probes === 1 && r.lo && Math.abs(r.hi[2] - r.lo[2]) > 0.005;
  }, { what: 'the recorded probe shown moving down and up by more than 5 mm' });
  await waitView(page, () => window.__rec.rows > 0 && window.__rec.depth > 0,
                 { timeoutMs: 20000, what: 'the recorded contacts shown while the probe pressed' });
  await waitView(page, () => window.__rec.plot > 100,
                 { what: 'the plot holding more than 100 recorded force samples' });
  console.log(`recorded: ${JSON.stringify(await page.evaluate(() => window.__rec))}`);
  fs.rmSync(dir, { recursive: true, force: true });
});
