// (b) Live scene changes: a body injected while the page is open appears
// (bodies, bodyIds, the scene revision), and goes when it is removed; a
// second page opened afterwards gets the whole current scene on connect.
import { runTest, serveScene, startViewer, openViewer, waitView, check } from './lib/harness.mjs';

runTest('view_bodies', async (ctx) => {
  const server = await serveScene(ctx, 'changes', [['base', 'box:0.1,0.1,0.01', '0,0,-0.01']]);
  const viewer = await startViewer(ctx, { server, scene: 'changes' });
  const page = await openViewer(ctx, viewer.url('/'));

  const ids = () => page.evaluate(() => [...window.hapticpdView.bodyIds].sort().join(','));
  await waitView(page, () => __count(window.hapticpdView.bodies) === 1 &&
                             __count(window.hapticpdView.bodyIds) === 1,
                 { what: 'the one body of the scene shown' });
  check(await ids() === 'base', `bodyIds ${await ids()} is [base]`);
  const rev0 = await page.evaluate(() => window.hapticpdView.revision);

  await server.inject('changes', 'newcomer', 'sphere:0.02', '0.03,0,0.02');
  await waitView(page, () => __count(window.hapticpdView.bodies) === 2 &&
                             window.hapticpdView.bodyIds.includes('newcomer'),
                 { what: "the injected body 'newcomer' shown (2 bodies)" });
  check(await ids() === 'base,newcomer', `bodyIds ${await ids()} is [base, newcomer]`);
  const rev1 = await page.evaluate(() => window.hapticpdView.revision);
  check(Number(rev1) > Number(rev0), `the scene revision grew on inject (${rev0} -> ${rev1})`);

  // A page opened now gets the whole current scene.
  const page2 = await openViewer(ctx, viewer.url('/'));
  await waitView(page2, () => __count(window.hapticpdView.bodies) === 2 &&
                              window.hapticpdView.bodyIds.includes('newcomer'),
                 { what: 'a second page shown both bodies on connect' });
  const h = await viewer.health();
  check(h.browsers >= 2, `/healthz counts both browsers: ${JSON.stringify(h)}`);
  await page2.close();
  ctx.pages.pop();

  await server.remove('changes', 'newcomer');
  await waitView(page, () => __count(window.hapticpdView.bodies) === 1 &&
                             !window.hapticpdView.bodyIds.includes('newcomer'),
                 { what: "the removed body 'newcomer' gone (1 body)" });
  check(await ids() === 'base', `bodyIds ${await ids()} is [base] again`);
  const rev2 = await page.evaluate(() => window.hapticpdView.revision);
  check(Number(rev2) > Number(rev1), `the scene revision grew on remove (${rev1} -> ${rev2})`);

  // The same id injected again (another shape) comes back: nothing cached by id alone.
  await server.inject('changes', 'newcomer', 'box:0.01,0.01,0.01', '-0.03,0,0.02');
  await waitView(page, () => __count(window.hapticpdView.bodies) === 2 &&
                             window.hapticpdView.bodyIds.includes('newcomer'),
                 { what: "'newcomer' shown again after being injected again" });
});
