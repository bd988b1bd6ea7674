// The page of `matlaber serve` in headless Chromium (tests/cli_serve.sh starts the server): a
// prompt typed and submitted with tiny settings, the progress bar moving with the job's events,
// the finished asset drawn by the viewer (pixels that are not background), the environment
// switched (the pixels change), a latent slider moved (the pixels change; at zero offset the
// decoded maps draw the baked maps' picture), the .glb downloaded through its link; no console errors, page
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
    problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`);
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
    await frame.evaluate(() => { window.viewer.latent.setOffset([0, 0, 0, 0]); window.viewer.setBackground(true); });
  }
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
