// The page of `matlaber serve` in headless Chromium (tests/cli_serve.sh starts the server): a
// prompt typed and submitted with tiny settings, the progress bar moving with the job's events,
// the finished asset drawn by the viewer (pixels that are not background), the environment
// switched (the pixels change), a latent slider moved (the pixels change; at zero offset the
// decoded maps draw the baked maps' picture), a region picked by a click (highlighted; an offset
// there changes fewer pixels than on the whole asset), moved toward another job's material, saved
// as a new job (listed, its .glb valid, opened), the .glb downloaded through its link; no console errors, page
// errors, failed requests, HTTP errors, or requests leaving the server.
// Usage: node tests/serve_check.mjs URL SETTINGS_JSON [SCREENSHOT_DIR]. Exit 0 pass, 1 fail, 77
// skip (no Chromium, no playwright-core, no WebGL 2).
import { createRequire } from 'node:module';
import { existsSync, readFileSync, mkdirSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import path from 'node:path';

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, '..', 'viewer', 'package.json'));
const [url, settings, shots] = process.argv.slice(2);
if (!url || !settings) { console.error('usage: serve_check.mjs URL SETTINGS_JSON [SCREENSHOT_DIR]'); process.exit(2); }
let chromium;
try { ({ chromium } = require('playwright-core')); } catch (e) { console.log('skip: playwright-core not installed in viewer/node_modules'); process.exit(77); }
const exe = process.env.CHROMIUM || ['/usr/bin/chromium', '/usr/bin/chromium-browser'].find((p) => existsSync(p));
if (!exe) { console.log('skip: no Chromium (/usr/bin/chromium; scripts/install-deps.sh installs it)'); process.exit(77); }
const origin = new URL(url).origin;

let failures = 0;
const t0 = Date.now();
const ok = (cond, what) => { console.log(`${cond ? 'ok  ' : 'FAIL'} ${what} [${((Date.now() - t0) / 1000).toFixed(1)} s]`); if (!cond) failures++; };
const problems = [];
let seen = [];
const browser = await chromium.launch({
  executablePath: exe,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
});
try {
  const page = await browser.newPage({ viewport: { width: 900, height: 560 }, acceptDownloads: true });
  page.on('console', (m) => { if (m.type() === 'error') problems.push(`console error: ${m.text()}`); });
  page.on('pageerror', (e) => problems.push(`page error: ${e.message}`));
  page.on('requestfailed', async (r) => {
    // the EventSource closed by the page at the job's end, and a download, are not failures; nor is
    // a request whose whole answer (200) had arrived: under load Chromium reported the viewer's
    // asset and environment maps aborted after their last byte, while the pixels show them used
    if (/\/events$|\/files\//.test(r.url())) return;
    const resp = await r.response().catch(() => null);
    if (resp && resp.status() === 200 && r.timing().responseEnd > 0) return;
    problems.push(`request failed: ${r.url()} ${r.failure()?.errorText} (frame ${r.frame() === page.mainFrame() ? 'the page' : r.frame().url()})`);
  });
  page.on('response', (r) => { if (r.status() >= 400) problems.push(`HTTP ${r.status()}: ${r.url()}`); });
  await page.route('**/*', (route) => {
    if (route.request().url().startsWith(origin)) return route.continue();
    problems.push(`a request outside the server: ${route.request().url()}`);
    return route.abort();
  });
  const shot = async (name) => { if (shots) { mkdirSync(shots, { recursive: true }); await page.screenshot({ path: path.join(shots, `server_${name}.png`) }); } };
  await page.goto(url);
  if (!(await page.evaluate(() => !!document.createElement('canvas').getContext('webgl2')))) {
    console.log('skip: this Chromium offers no WebGL 2 (not even SwiftShader)');
    await browser.close(); process.exit(77);
  }
  // make
  await page.fill('#prompt', 'a gold goblet');
  await page.fill('#seed', '3');
  await page.fill('#extra', settings);
  await shot('1_make');
  await page.click('#submit');
  await page.waitForFunction(() => window.serveApp.selected, null, { timeout: 20000 });
  const id = await page.evaluate(() => window.serveApp.selected);
  ok(/^job-\d+$/.test(id), `submitted: ${id}`);
  // watch: the bar moves with the events
  await page.waitForFunction(() => window.serveApp.last && ['progress', 'end', 'job'].includes(window.serveApp.last.event), null, { timeout: Number(process.env.MLB_SERVE_WAIT_MS || 120000) });
  const bar = await page.evaluate(() => parseFloat(document.getElementById('job-bar').style.width));
  ok(bar > 0, `the progress bar moved (${bar}%) with ${await page.evaluate(() => window.serveApp.events)} events`);
  await shot('2_watch');
  // look: the viewer in its frame draws the asset
  await page.waitForFunction(() => { const f = document.getElementById('view'); return !f.hidden && f.contentWindow.viewer && f.contentWindow.viewer.ready && f.contentWindow.viewer.frames > 0; },
    null, { timeout: Number(process.env.MLB_SERVE_WAIT_MS || 180000) });   // (a full-size job for the docs' pictures: longer)
  ok(true, 'the viewer shows the finished asset');
  const frame = page.frames().find((f) => f.url().includes(`/view/${id}/`));
  ok(!!frame, 'the viewer frame is /view/ID/');
  const grab = (name) => frame.evaluate((n) => {
    window.viewer.renderNow();
    const c = document.querySelector('#view canvas');
    const t = document.createElement('canvas');
    t.width = c.width; t.height = c.height;
    t.getContext('2d').drawImage(c, 0, 0);
    (window.__px ||= {})[n] = t.getContext('2d').getImageData(0, 0, t.width, t.height).data;
  }, name);
  const fg = (n) => frame.evaluate((k) => {   // share of pixels off the flat background #202124
    const p = window.__px[k]; let m = 0;
    for (let i = 0; i < p.length; i += 4) m += Math.abs(p[i] - 0x20) + Math.abs(p[i + 1] - 0x21) + Math.abs(p[i + 2] - 0x24) > 6;
    return m / (p.length / 4);
  }, n);
  const diff = (a, b) => frame.evaluate(([x, y]) => {
    const p = window.__px[x], q = window.__px[y]; let s = 0;
    for (let i = 0; i < p.length; i += 4) s += Math.abs(p[i] - q[i]) + Math.abs(p[i + 1] - q[i + 1]) + Math.abs(p[i + 2] - q[i + 2]);
    return s / (p.length / 4) / 3;
  }, [a, b]);
  await frame.evaluate(() => window.viewer.setBackground(false));
  await grab('first');
  const cover = await fg('first');
  ok(cover > 0.01 && cover < 0.95, `the asset covers ${(100 * cover).toFixed(1)}% of the viewer`);
  await shot('3_look');
  const envs = await frame.evaluate(() => [...document.getElementById('env').options].map((o) => o.value));
  await frame.evaluate(() => window.viewer.setBackground(true));
  await grab('env0');
  await frame.evaluate((e) => window.viewer.setEnvironment(e), envs[1]);
  await grab('env1');
  const d = await diff('env0', 'env1');
  ok(d > 1, `switching ${envs[0]} -> ${envs[1]} changes the pixels (${d.toFixed(2)})`);
  await shot('4_environment');
  await frame.evaluate(() => window.viewer.setChannel('normals'));
  await grab('normals');
  const dn = await diff('env1', 'normals');
  ok(dn > 1, `the normals view differs from the shaded one (${dn.toFixed(2)})`);
  await frame.evaluate(() => window.viewer.setChannel('shaded'));
  // edit the material in the prior's latent space (a latent-mode job: the default)
  const latent = await frame.evaluate(() => window.viewer.latent.available);
  ok(latent, 'the latent editor is offered');
  if (latent) {
    await frame.evaluate(() => { window.viewer.setBackground(false); window.viewer.latent.setDecoded(false); });
    await grab('baked');
    await frame.evaluate(() => window.viewer.latent.setDecoded(true));
    await grab('decoded');
    const dz = await diff('baked', 'decoded');
    ok(dz < 1, `at zero offset the decoder in the shader draws the baked maps' picture (mean |difference| ${dz.toFixed(2)} of 255)`);
    // the first slider moved by hand, as a person would
    const slider = frame.locator('#latent-sliders input').first();
    const box = await slider.boundingBox();
    if (box) await page.mouse.click(box.x + box.width - 2, box.y + box.height / 2);
    else await frame.evaluate(() => window.viewer.latent.setOffset([1, 0, 0, 0]));   // (the panel out of view)
    await grab('moved');
    const dm = await diff('decoded', 'moved');
    // (the asset covers a few % of the frame: 0.3 is 15 times the zero-offset difference)
    ok(dm > 0.3, `moving a latent slider changes the pixels (${dm.toFixed(2)})`);
    await shot('6_latent');
    await frame.evaluate(() => window.viewer.latent.setOffset([0, 0, 0, 0]));
    // a region: a click on the asset picks the material under it (the texel through the raycast);
    // the region's texels shown in the kd view, then the same offset on the region and on the whole
    // (a point of the asset that the panel does not cover, in the frame's coordinates, clicked with the mouse)
    const fb = await page.locator('#view').boundingBox();
    await frame.evaluate(() => { document.getElementById('panel').style.visibility = 'hidden'; });   // (it may cover the asset)
    let picked = null;
    for (const fy of [0.5, 0.45, 0.55, 0.4, 0.6]) for (const fx of [0.5, 0.55, 0.6, 0.45, 0.65, 0.4]) {
      if (picked) break;
      const hit = await frame.evaluate(([u, v]) => {
        const r = document.querySelector('#view canvas').getBoundingClientRect();
        const x = r.left + u * r.width, y = r.top + v * r.height;
        return document.elementFromPoint(x, y)?.tagName === 'CANVAS' && window.viewer.latent.texelAt(x, y) ? [x, y] : null;
      }, [fx, fy]);
      if (!hit) continue;
      await page.mouse.click(fb.x + hit[0], fb.y + hit[1]);
      picked = await frame.evaluate(() => window.viewer.latent.edit.region);
    }
    await frame.evaluate(() => { document.getElementById('panel').style.visibility = ''; });
    ok(!!picked, `a click on the asset picks a region (texel ${picked?.texel})`);
    if (picked) {
      await frame.evaluate(() => window.viewer.setChannel('kd'));
      await grab('kd');
      await frame.evaluate(() => window.viewer.latent.setHighlight(true));
      await grab('kd_region');
      const lit = await frame.evaluate(([a, b]) => {   // pixels the highlight turned orange
        const p = window.__px[a], q = window.__px[b]; let n = 0, fgn = 0;
        for (let i = 0; i < p.length; i += 4) {
          const f = Math.abs(p[i] - 0x20) + Math.abs(p[i + 1] - 0x21) + Math.abs(p[i + 2] - 0x24) > 6;
          fgn += f; n += f && Math.abs(p[i] - q[i]) + Math.abs(p[i + 1] - q[i + 1]) + Math.abs(p[i + 2] - q[i + 2]) > 6;
        }
        return [n, fgn];
      }, ['kd', 'kd_region']);
      ok(lit[0] > 0 && lit[0] < lit[1], `the region shows: ${lit[0]} of the asset's ${lit[1]} pixels highlighted`);
      await shot('7_region');
      await frame.evaluate(() => { window.viewer.latent.setHighlight(false); window.viewer.latent.setOffset([2, 0, 0, 0]); });
      await grab('kd_region_moved');
      await frame.evaluate(() => { window.viewer.latent.whole(); });
      await grab('kd_whole_moved');
      const changed = (a, b) => frame.evaluate(([x, y]) => {
        const p = window.__px[x], q = window.__px[y]; let n = 0;
        for (let i = 0; i < p.length; i += 4) n += Math.abs(p[i] - q[i]) + Math.abs(p[i + 1] - q[i + 1]) + Math.abs(p[i + 2] - q[i + 2]) > 6;
        return n;
      }, [a, b]);
      const nr = await changed('kd', 'kd_region_moved'), nw = await changed('kd', 'kd_whole_moved');
      ok(nr > 0 && nr < nw, `the offset on the region changes ${nr} pixels, on the whole asset ${nw}`);
      const outside = await frame.evaluate(() => {   // pixels the region's offset changed that the highlight did not mark
        const [p, h, m] = ['kd', 'kd_region', 'kd_region_moved'].map((k) => window.__px[k]);
        const d = (a, i) => Math.abs(p[i] - a[i]) + Math.abs(p[i + 1] - a[i + 1]) + Math.abs(p[i + 2] - a[i + 2]) > 6;
        let n = 0;
        for (let i = 0; i < p.length; i += 4) n += d(m, i) && !d(h, i);
        return n;
      });
      // (a texel at the region's edge filters into its neighbours' pixels: a few, not more)
      ok(outside <= 0.05 * nr + 10, `the region's offset changes only the region: ${outside} changed pixels outside the highlight`);
      const others = await frame.evaluate(() => [...document.getElementById('latent-toward').options].map((o) => o.value).filter(Boolean));
      ok(others.length > 0, `other finished jobs offered to move toward: ${others.join(', ')}`);
      // save as a new job (the whole asset moved): the server re-applies the edit; the new job is
      // listed, done, with a valid .glb and the OBJ set
      const saved = await frame.evaluate(() => window.viewer.latent.saveAsNew().then((j) => j.id));
      ok(/^job-\d+$/.test(saved), `saved as a new job: ${saved}`);
      await page.waitForFunction((sid) => [...document.querySelectorAll('#jobs tr')].some((r) => r.dataset.id === sid), saved, { timeout: 20000 });
      ok(true, `${saved} is in the page's list`);
      const job = await page.evaluate((sid) => fetch(`/api/jobs/${sid}`).then((r) => r.json()), saved);
      ok(job.state === 'done' && job.files.includes('asset.glb') && job.files.includes('asset_kd.png'), `${saved}: done, with asset.glb and the OBJ set`);
      const head = await page.evaluate((sid) => fetch(`/api/jobs/${sid}/files/asset.glb`).then((r) => r.arrayBuffer()).then((b) => [new TextDecoder().decode(b.slice(0, 4)), b.byteLength]), saved);
      ok(head[0] === 'glTF' && head[1] > 1000, `${saved}'s asset.glb is a .glb (${head[1]} bytes)`);
      // toward that job's material (its mean code: this one's moved by the offset), the region only
      await frame.evaluate((t) => { window.viewer.latent.pickTexel(...t); window.viewer.latent.setOffset([0, 0, 0, 0]); }, picked.texel);
      ok(await frame.evaluate((o) => window.viewer.latent.setToward(o), saved), `toward ${saved}'s material`);
      await frame.evaluate(() => window.viewer.latent.setT(1));
      await grab('kd_toward');
      const nt = await changed('kd', 'kd_toward');
      ok(nt > 0 && nt < nw, `t 1 toward it changes ${nt} pixels (the region's)`);
      await frame.evaluate(() => window.viewer.setChannel('shaded'));
      await shot('8_toward');
      await frame.evaluate(() => { window.viewer.latent.setT(0); window.viewer.latent.setToward(''); window.viewer.latent.whole(); });
      await page.evaluate((sid) => window.serveApp.select(sid), saved);
      await page.waitForFunction((sid) => { const f = document.getElementById('view'); return f.contentWindow.location.pathname === `/view/${sid}/` && f.contentWindow.viewer && f.contentWindow.viewer.ready && f.contentWindow.viewer.frames > 0; },
        saved, { timeout: 60000 });
      ok(true, `${saved} opens in the viewer`);
      await shot('9_saved');
      await page.evaluate((sid) => window.serveApp.select(sid), id);
      await page.waitForFunction((sid) => { const f = document.getElementById('view'); return f.contentWindow.location.pathname === `/view/${sid}/` && f.contentWindow.viewer && f.contentWindow.viewer.ready; },
        id, { timeout: 60000 });
    }
  }
  const frame2 = page.frames().find((f) => f.url().includes(`/view/${id}/`));
  if (frame2) await frame2.evaluate(() => { window.viewer.latent.setOffset?.([0, 0, 0, 0]); window.viewer.setBackground(true); });
  // compare with another finished job, side by side (when the server has one)
  const other = await page.evaluate((me) => [...document.getElementById('compare').options].map((o) => o.value).find((v) => v && v !== me), id);
  if (other) {
    await page.selectOption('#compare', other);
    await page.waitForFunction(() => { const f = document.getElementById('view2'); return !f.hidden && f.contentWindow.viewer && f.contentWindow.viewer.ready && f.contentWindow.viewer.frames > 0; },
      null, { timeout: 120000 });
    const both = await page.evaluate(() => [...document.querySelectorAll('#look iframe')].filter((f) => !f.hidden).map((f) => Math.round(f.getBoundingClientRect().width)));
    ok(both.length === 2 && both[0] > 100 && both[1] > 100, `${other} beside it: two viewers (${both.join(' + ')} px wide)`);
    await shot('5_compare');
  } else console.log('(no other finished job to compare with)');
  // download the .glb through its link
  const link = page.locator('#downloads a', { hasText: 'asset.glb' });
  ok(await link.count() === 1, 'a download link for asset.glb');
  const [download] = await Promise.all([page.waitForEvent('download'), link.click()]);
  const saved = await download.path();
  const bytes = saved ? readFileSync(saved) : Buffer.alloc(0);
  ok(bytes.subarray(0, 4).toString() === 'glTF', `the download is a .glb (${bytes.length} bytes)`);
  seen = problems.slice();   // (closing the browser aborts whatever is still open)
} finally {
  await browser.close();
}
ok(seen.length === 0, `no console errors, page errors, HTTP errors or outside requests${seen.length ? ':\n  ' + seen.join('\n  ') : ''}`);
console.log(failures ? `${failures} failed` : 'all passed');
process.exit(failures ? 1 : 0);
