// Headless check of a folder written by mlb_viewer_write (tests/cli_viewer.sh): serves the folder
// from a local HTTP server on 127.0.0.1 (any port), opens it in Chromium through playwright-core,
// refuses every request that leaves that server, and checks that
//   - the page loads without console errors, page errors or failed requests,
//   - the asset is drawn (pixels that differ from the flat background),
//   - the picture changes when the light slider turns the environment, and with the map toggles,
//   - with a latent-mode asset: the decoder in the shader at zero offset draws what the baked maps
//     draw (shaded and each map), the latent sliders change the picture, and zero restores it.
// Usage: node tests/viewer_check.mjs DIR [SCREENSHOT_DIR]. Exit 0 pass, 1 fail, 77 skip
// (no Chromium or no playwright-core in viewer/node_modules).
import { createRequire } from 'node:module';
import { existsSync, readFileSync, writeFileSync, mkdirSync } from 'node:fs';
import { createServer } from 'node:http';
import { fileURLToPath } from 'node:url';
import path from 'node:path';

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, '..', 'viewer', 'package.json'));
const [dir, shots] = process.argv.slice(2);
if (!dir) { console.error('usage: viewer_check.mjs DIR [SCREENSHOT_DIR]'); process.exit(2); }
let chromium;
try { ({ chromium } = require('playwright-core')); } catch (e) { console.log('skip: playwright-core not installed in viewer/node_modules'); process.exit(77); }
const exe = process.env.CHROMIUM || ['/usr/bin/chromium', '/usr/bin/chromium-browser'].find((p) => existsSync(p));
if (!exe) { console.log('skip: no Chromium (/usr/bin/chromium; scripts/install-deps.sh installs it)'); process.exit(77); }

const types = { '.html': 'text/html', '.js': 'text/javascript', '.json': 'application/json', '.glb': 'model/gltf-binary',
                '.hdr': 'application/octet-stream', '.png': 'image/png' };
const root = path.resolve(dir);
const server = createServer((req, res) => {
  const rel = decodeURIComponent(new URL(req.url, 'http://x').pathname);
  const file = path.join(root, rel.endsWith('/') ? rel + 'index.html' : rel);
  if (!file.startsWith(root) || !existsSync(file)) { res.writeHead(404); res.end(); return; }
  res.writeHead(200, { 'Content-Type': types[path.extname(file)] || 'application/octet-stream' });
  res.end(readFileSync(file));
});
await new Promise((r) => server.listen(0, '127.0.0.1', r));
const origin = `http://127.0.0.1:${server.address().port}`;

let failures = 0;
const t0 = Date.now();
const ok = (cond, what) => { console.log(`${cond ? 'ok  ' : 'FAIL'} ${what} [${((Date.now() - t0) / 1000).toFixed(1)} s]`); if (!cond) failures++; };
const problems = [];
const browser = await chromium.launch({
  executablePath: exe,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
});
try {
  const page = await browser.newPage({ viewport: { width: 320, height: 240 }, acceptDownloads: true });
  page.on('console', (m) => {
    if (m.type() === 'error') problems.push(`console error: ${m.text()}`);
    else if (m.type() === 'warning') console.log(`note: console warning: ${m.text()}`);
  });
  page.on('pageerror', (e) => problems.push(`page error: ${e.message}`));
  page.on('requestfailed', (r) => problems.push(`request failed: ${r.url()} ${r.failure()?.errorText}`));
  page.on('response', (r) => { if (r.status() >= 400) problems.push(`HTTP ${r.status()}: ${r.url()}`); });
  await page.route('**/*', (route) => {
    if (route.request().url().startsWith(origin)) return route.continue();
    problems.push(`network request outside the folder: ${route.request().url()}`);
    return route.abort();
  });
  // a Chromium without any WebGL 2 (no SwiftShader either) cannot run three.js: skip, not fail
  await page.goto(`${origin}/viewer.json`);
  if (!(await page.evaluate(() => !!document.createElement('canvas').getContext('webgl2')))) {
    console.log('skip: this Chromium offers no WebGL 2 (not even SwiftShader)');
    await browser.close(); server.close(); process.exit(77);
  }
  await page.goto(`${origin}/`);
  await page.waitForFunction(() => window.viewer && window.viewer.ready && window.viewer.frames > 0, null, { timeout: 60000 });

  // Draws one frame and keeps its pixels in the page under `name` (they never travel to node).
  const grab = async (name) => {
    await page.evaluate((n) => {
      window.viewer.renderNow();
      const c = document.querySelector('#view canvas');
      const t = document.createElement('canvas');
      t.width = c.width; t.height = c.height;
      const g = t.getContext('2d');
      g.drawImage(c, 0, 0);
      (window.__px ||= {})[n] = g.getImageData(0, 0, t.width, t.height).data;
    }, name);
    if (shots) { mkdirSync(shots, { recursive: true }); writeFileSync(path.join(shots, `${name}.png`), await page.locator('#view canvas').screenshot()); }
    return name;
  };
  // share of pixels that differ from the flat background #202124
  const fg = (a) => page.evaluate((n) => {
    const p = window.__px[n]; let k = 0;
    for (let i = 0; i < p.length; i += 4) k += Math.abs(p[i] - 0x20) + Math.abs(p[i + 1] - 0x21) + Math.abs(p[i + 2] - 0x24) > 6;
    return k / (p.length / 4);
  }, a);
  // mean absolute difference per channel, 0..255
  const diff = (a, b) => page.evaluate(([x, y]) => {
    const p = window.__px[x], q = window.__px[y]; let s = 0;
    for (let i = 0; i < p.length; i += 4) s += Math.abs(p[i] - q[i]) + Math.abs(p[i + 1] - q[i + 1]) + Math.abs(p[i + 2] - q[i + 2]);
    return s / (p.length / 4) / 3;
  }, [a, b]);
  const f2 = (x) => x.toFixed(2);

  await page.evaluate(() => window.viewer.setBackground(false));
  const a = await grab('shaded_0');
  const cover = await fg(a);
  ok(cover > 0.05 && cover < 0.95, `the asset covers ${(100 * cover).toFixed(1)}% of the view`);
  await page.evaluate(() => window.viewer.setRotation(120));
  const b = await grab('shaded_120');
  const d1 = await diff(a, b);
  ok(d1 > 0.5, `turning the light 120 degrees changes the picture (mean |difference| ${d1.toFixed(2)} of 255)`);
  ok(Math.abs((await fg(b)) - cover) < 0.01, 'the silhouette stays where it was');
  await page.evaluate(() => window.viewer.setRotation(0));
  const a2 = await grab('shaded_0_again');
  const d2 = await diff(a, a2);
  ok(d2 < 0.5, `turning it back restores the picture (${f2(d2)})`);
  const views = {};
  for (const ch of ['kd', 'ks', 'roughness']) {
    await page.evaluate((c) => window.viewer.setChannel(c), ch);
    views[ch] = await grab(ch);
    const d = await diff(views[ch], a);
    ok(d > 1, `the ${ch} view differs from the shaded one (${f2(d)})`);
  }
  await page.evaluate(() => window.viewer.setRotation(200));
  await page.evaluate(() => window.viewer.setChannel('kd'));
  const kd2 = await grab('kd_200');
  const d3 = await diff(kd2, views.kd);
  ok(d3 < 0.5, `the unlit kd view does not change with the light (${f2(d3)})`);
  await page.evaluate(() => { window.viewer.setChannel('shaded'); window.viewer.setBackground(true); });
  const envs = await page.evaluate(() => [...document.getElementById('env').options].map((o) => o.value));
  if (envs.length > 1) {
    const first = await grab(`${envs[0]}_background`);
    await page.evaluate((e) => window.viewer.setEnvironment(e), envs[1]);
    const second = await grab(`${envs[1]}_background`);
    const d4 = await diff(first, second);
    ok(d4 > 5, `switching from ${envs[0]} to ${envs[1]} changes the picture (${f2(d4)})`);
  }
  // The latent editor (viewer/latent.js), where the folder has one (MLB_EXPECT_LATENT=1: it must)
  const latent = await page.evaluate(() => window.viewer.latent.available);
  if (process.env.MLB_EXPECT_LATENT === '1') ok(latent, 'the latent editor is offered');
  if (!latent) ok(await page.evaluate(() => document.getElementById('latent').hidden), 'no latent editor without its files');
  if (latent) {
    const maxdiff = (x, y) => page.evaluate(([x, y]) => {
      const p = window.__px[x], q = window.__px[y]; let m = 0;
      for (let i = 0; i < p.length; i++) if ((i & 3) !== 3) m = Math.max(m, Math.abs(p[i] - q[i]));
      return m;
    }, [x, y]);
    await page.evaluate(() => { window.viewer.setBackground(false); window.viewer.setRotation(0); });
    for (const ch of ['shaded', 'kd', 'ks', 'roughness']) {
      await page.evaluate((c) => { window.viewer.setChannel(c); window.viewer.latent.setDecoded(false); }, ch);
      const baked = await grab(`latent_${ch}_baked`);
      await page.evaluate(() => window.viewer.latent.setDecoded(true));
      const dec = await grab(`latent_${ch}_decoded`);
      const d = await diff(baked, dec), m = await maxdiff(baked, dec);
      ok(d < 1, `${ch}: at zero offset the decoder in the shader draws the baked maps' picture (mean |difference| ${f2(d)} of 255, largest ${m})`);
    }
    await page.evaluate(() => window.viewer.setChannel('shaded'));
    const zero = await grab('latent_zero');
    await page.evaluate(() => window.viewer.latent.setOffset([1, -1, 1, -1]));
    const moved = await grab('latent_moved');
    const dm = await diff(zero, moved);
    ok(dm > 2, `moving the latent sliders changes the picture (${f2(dm)})`);
    ok(Math.abs((await fg(moved)) - (await fg(zero))) < 0.01, 'the silhouette stays where it was');
    await page.evaluate(() => window.viewer.latent.setOffset([0, 0, 0, 0]));
    const back = await grab('latent_back');
    const db = await diff(zero, back);
    ok(db < 0.5, `the sliders back at zero restore it (${f2(db)})`);
    // a region: a click on the asset picks the material under it; in the kd view its highlight
    // marks some of the asset's pixels, and an offset there changes those and no others
    await page.evaluate(() => window.viewer.setChannel('kd'));
    const kd0 = await grab('region_kd');
    let pickedAt = null;   // a point of the asset that the panel does not cover, clicked with the mouse
    await page.evaluate(() => { document.getElementById('panel').style.visibility = 'hidden'; });   // (it covers most of this small view)
    for (const fy of [0.5, 0.45, 0.55, 0.4, 0.6]) for (const fx of [0.5, 0.55, 0.6, 0.65, 0.7, 0.45]) {
      if (pickedAt) break;
      const hit = await page.evaluate(([u, v]) => {
        const x = u * innerWidth, y = v * innerHeight;
        return document.elementFromPoint(x, y)?.tagName === 'CANVAS' && window.viewer.latent.texelAt(x, y) ? [x, y] : null;
      }, [fx, fy]);
      if (!hit) continue;
      await page.mouse.click(hit[0], hit[1]);
      pickedAt = await page.evaluate(() => window.viewer.latent.edit.region?.texel);
    }
    await page.evaluate(() => { document.getElementById('panel').style.visibility = ''; });
    ok(!!pickedAt, `a click on the asset picks a region (texel ${pickedAt})`);
    if (pickedAt) {
      await page.evaluate(() => window.viewer.latent.setHighlight(true));
      const hl = await grab('region_highlight');
      await page.evaluate(() => { window.viewer.latent.setHighlight(false); window.viewer.latent.setOffset([1, -1, 1, -1]); });
      const rm = await grab('region_moved');
      await page.evaluate(() => window.viewer.latent.whole());
      const wm = await grab('whole_moved');
      const counts = await page.evaluate(([k, h, r, w]) => {
        const [p, q, m, v] = [k, h, r, w].map((n) => window.__px[n]);
        const d = (a, i) => Math.abs(p[i] - a[i]) + Math.abs(p[i + 1] - a[i + 1]) + Math.abs(p[i + 2] - a[i + 2]) > 6;
        const c = { marked: 0, region: 0, outside: 0, whole: 0 };
        for (let i = 0; i < p.length; i += 4) {
          c.marked += d(q, i); c.region += d(m, i); c.outside += d(m, i) && !d(q, i); c.whole += d(v, i);
        }
        return c;
      }, [kd0, hl, rm, wm]);
      ok(counts.marked > 0 && counts.region > 0 && counts.region < counts.whole,
         `the region's offset changes ${counts.region} pixels (${counts.marked} highlighted), the whole asset's ${counts.whole}`);
      ok(counts.outside <= 0.05 * counts.region + 10, `and none outside the highlight but at its edge (${counts.outside})`);
      ok(await page.evaluate(() => document.getElementById('latent-served').hidden), 'no "toward" or "save as new" without the server');
    }
    await page.evaluate(() => { window.viewer.setChannel('shaded'); window.viewer.latent.setOffset([0, 0, 0, 0]); });
    // save: the edited maps as three PNG downloads, of the latent texture's size
    await page.evaluate(() => window.viewer.latent.setOffset([1, -1, 1, -1]));
    const got = [];
    page.on('download', (d) => got.push(d));
    await page.evaluate(() => document.getElementById('latent-save').click());   // (the panel may pass the small view)
    for (let i = 0; i < 50 && got.length < 3; i++) await page.waitForTimeout(100);
    const names = got.map((d) => d.suggestedFilename()).sort();
    ok(names.join() === 'asset_kd.png,asset_ks.png,asset_roughness.png', `save downloads the edited maps (${names.join(', ')})`);
    const size = await page.evaluate(async () => (await (await fetch('asset.decoder.json')).json()).latent.size);
    for (const d of got) {
      const b = readFileSync(await d.path());
      const w = b.readUInt32BE(16), h = b.readUInt32BE(20);
      ok(b.subarray(1, 4).toString() === 'PNG' && w === size && h === size, `${d.suggestedFilename()}: a ${w}x${h} PNG`);
    }
  }
} finally {
  await browser.close();
  server.close();
}
ok(problems.length === 0, `no console errors, page errors or stray requests${problems.length ? ':\n  ' + problems.join('\n  ') : ''}`);
console.log(failures ? `${failures} failed` : 'all passed');
process.exit(failures ? 1 : 0);
