// Browser conformance of the plugin: every valid sample of samples/ and a baked duck, drawn
// by DNRGLTFPlugin through three's WebGLRenderer in headless chromium (SwiftShader WebGL2),
// read back and compared with the committed references and with `dnr render` of the same
// camera, at the spec's tolerance (99.5 % of pixels within 2/255, mean at most 0.5/255).
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { mkdirSync, readFileSync, writeFileSync, existsSync } from 'node:fs';
import { join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { serve } from '../scripts/serve.mjs';
import { launch, openHarness, decodePng, compare, fromB64, readJson, lookAt, editGlbJson } from './lib.mjs';

const here = resolve(fileURLToPath(new URL('..', import.meta.url)));
const repo = resolve(here, '..', '..');
const samples = join(repo, 'samples');
const out = resolve(process.env.DNR_OUT || join(here, 'test-output'));
process.env.DNR_OUT = out;
mkdirSync(out, { recursive: true });
const bin = (name) => {
  for (const p of ['release', 'debug']) {
    const f = join(repo, 'target', p, name);
    if (existsSync(f)) return f;
  }
  throw new Error(`${name} is not built: cargo build -p ${name === 'dnr' ? 'dnr-cli' : 'dnr-bake'}`);
};

const EXTRA_SIZES = [[64, 48], [257, 131]];
let server;
let browser;
let page;
const results = [];

function dnrRender(asset, c, w, h, file) {
  execFileSync(bin('dnr'), ['render', asset, '--look-at', [...c.eye, ...c.target].join(','),
    '--fov', String(c.fovY), '--size', `${w}x${h}`, '-o', file], { stdio: 'pipe' });
  return decodePng(readFileSync(file)).rgba;
}

function report(asset, what, size, cmp) {
  const line = `${asset} ${size} vs ${what}: ${(100 * cmp.within).toFixed(2)} % within 2/255, mean ${cmp.mean.toFixed(3)}/255`;
  results.push(line);
  console.log(line);
  assert.ok(cmp.pass, `${line} (worst ${cmp.worst})`);
}

async function checkAsset(url, file, cameras, { references = true } = {}) {
  const info = await page.evaluate((u) => harness.load(u), url);
  assert.equal(info.status, 'gpu', `${url}: ${JSON.stringify(info)}`);
  for (const c of cameras) {
    const sizes = [[c.width, c.height], ...EXTRA_SIZES];
    for (const [w, h] of sizes) {
      const k = w === c.width && h === c.height && c.fx ? c : lookAt(c.eye, c.target, c.fovY, w, h);
      const gpu = fromB64((await page.evaluate((kk) => harness.gpu(kk), k)).rgba);
      const size = `${c.name} ${w}x${h}`;
      if (references && k === c) {
        report(url, 'reference', size, compare(decodePng(readFileSync(join(samples, c.png))).rgba, gpu));
      }
      const ref = dnrRender(file, c, w, h, join(out, `render-${file.split('/').pop()}-${c.name}-${w}x${h}.png`));
      report(url, 'dnr render', size, compare(ref, gpu));
    }
  }
}

before(async () => {
  server = await serve(0);
  browser = await launch();
  page = await openHarness(browser, server.url);
});

after(async () => {
  await browser?.close();
  await server?.close();
  console.log(`\n${results.length} comparisons:\n${results.join('\n')}`);
});

const cameras = readJson(join(samples, 'references', 'cameras.json'));
for (const [sample, list] of Object.entries(cameras)) {
  test(`${sample} matches the references and dnr render`, async () => {
    await checkAsset(`/samples/${sample}`, join(samples, sample), list);
  });
}

test('a baked duck matches dnr render', async () => {
  const duck = join(out, 'duck.glb');
  if (!existsSync(duck)) {
    execFileSync(bin('dnr-bake'), [join(repo, '..', 'shared', 'captures', 'duck-tiny'), '-o', duck,
      '--preset', 'fast', '--steps', '60'], { stdio: 'pipe' });
  }
  const cams = [
    { name: 'side', eye: [2.6, 0.9, 2.3], target: [0, 0.05, 0], fovY: 40, width: 128, height: 128 },
    { name: 'above', eye: [-1.2, 2.9, 2.1], target: [0.02, 0, 0.01], fovY: 40, width: 128, height: 128 },
  ];
  await checkAsset('/out/duck.glb', duck, cams, { references: false });
});

test('the example viewer shows the baked duck as dnr render does', async () => {
  const duck = join(out, 'duck.glb');
  assert.ok(existsSync(duck), 'the duck test bakes it first');
  const c = { eye: [2.4, 1.1, 2.2], target: [0, 0, 0], fovY: 40 };
  const [w, h] = [200, 150];
  const view = await browser.newPage();
  const errors = [];
  view.on('pageerror', (e) => errors.push(String(e)));
  await view.goto(`${server.url}/example/?asset=/out/duck.glb&eye=${c.eye}&target=${c.target}&fov=${c.fovY}&size=${w}x${h}&ui=0`);
  await view.waitForFunction(() => window.viewer !== undefined);
  assert.equal(await view.evaluate(() => window.viewer.ready), 'gpu');
  const frames = () => view.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  await frames();
  const shot = async (file) => {
    const png = await view.locator('canvas').screenshot({ path: join(out, file) });
    return decodePng(png);
  };
  const neural = await shot('example-neural.png');
  assert.equal(neural.width, w);
  // dnr render of the same camera, over the viewer's white background.
  const ref = dnrRender(duck, c, w, h, join(out, 'example-dnr-render.png'));
  const over = new Uint8Array(ref.length);
  for (let i = 0; i < ref.length; i += 4) {
    const a = ref[i + 3] / 255;
    for (let k = 0; k < 3; k++) over[i + k] = Math.floor(255 * (a * ref[i + k] / 255 + (1 - a)) + 0.5);
    over[i + 3] = 255;
  }
  report('example viewer canvas (duck)', 'dnr render over white', `${w}x${h}`, compare(over, neural.rgba));
  await view.evaluate(() => window.viewer.setNeural(false));
  await frames();
  const fallback = await shot('example-fallback.png');
  const changed = fallback.rgba.filter((v, i) => Math.abs(v - neural.rgba[i]) > 8).length;
  assert.ok(changed > 100, `the fallback looks different from the neural layer (${changed} values differ)`);
  assert.deepEqual(errors, []);
  await view.close();
});

test('the forced CPU path gives the GPU result', async () => {
  const c = cameras['valid/scene_multi_primitive.glb'][0];
  await page.evaluate((u) => harness.load(u), '/samples/valid/scene_multi_primitive.glb');
  const gpu = fromB64((await page.evaluate((k) => harness.gpu(k), c)).rgba);
  const cpuPage = await openHarness(browser, server.url, '?cpu');
  const info = await cpuPage.evaluate((u) => harness.load(u), '/samples/valid/scene_multi_primitive.glb');
  assert.equal(info.status, 'cpu');
  const cpu = fromB64((await cpuPage.evaluate((k) => harness.cpu(k), c)).rgba);
  await cpuPage.close();
  report('scene_multi_primitive', 'forced CPU path', c.name, compare(cpu, gpu));
  assert.deepEqual(cpu, decodePng(readFileSync(join(samples, c.png))).rgba, 'the wasm runtime reproduces the reference exactly');
});

const SUPERSAMPLED = 'valid/unet_supersample2.glb';
test('a subsample G-buffer beyond the GPU limits falls back to pixel-centre features', { skip: !cameras[SUPERSAMPLED] }, async () => {
  // What the fallback draws is the asset without `supersample` (a revision 1.2 reader's view).
  const plain = join(out, 'unet_supersample2-s1.glb');
  writeFileSync(plain, editGlbJson(readFileSync(join(samples, SUPERSAMPLED)), (j) => {
    for (const r of j.extensions.EXT_deferred_neural_rendering.renderers) delete r.supersample;
  }));
  const c = cameras[SUPERSAMPLED][0];
  const limited = await openHarness(browser, server.url);
  await limited.evaluate((n) => harness.limitTargets(n), 2 * Math.max(c.width, c.height) - 1);
  assert.equal((await limited.evaluate((u) => harness.load(u), `/samples/${SUPERSAMPLED}`)).status, 'gpu');
  const gpu = fromB64((await limited.evaluate((k) => harness.gpu(k), c)).rgba);
  const logs = await limited.evaluate(() => harness.logs);
  assert.ok(logs.some((l) => l.startsWith('warn') && l.includes('2x2 subsample G-buffer') && l.includes('pixel-centre')), logs.join('\n'));
  assert.deepEqual(limited.errors, []);
  await limited.close();
  const ref = dnrRender(plain, c, c.width, c.height, join(out, `render-unet_supersample2-s1-${c.name}.png`));
  report(SUPERSAMPLED, 'dnr render without supersample (over the limit)', c.name, compare(ref, gpu));
});

test('the forced CPU path draws a supersampled sample as its reference', { skip: !cameras[SUPERSAMPLED] }, async () => {
  const c = cameras[SUPERSAMPLED][0];
  const cpuPage = await openHarness(browser, server.url, '?cpu');
  assert.equal((await cpuPage.evaluate((u) => harness.load(u), `/samples/${SUPERSAMPLED}`)).status, 'cpu');
  const cpu = fromB64((await cpuPage.evaluate((k) => harness.cpu(k), c)).rgba);
  await cpuPage.close();
  report(SUPERSAMPLED, 'forced CPU path vs reference', c.name, compare(decodePng(readFileSync(join(samples, c.png))).rgba, cpu));
});

test('an invalid sample shows the fallback and logs its codes', async () => {
  const info = await page.evaluate((u) => harness.load(u), '/samples/invalid/weights_checksum.glb');
  assert.equal(info.status, 'fallback');
  assert.deepEqual(info.report.blocking, ['WEIGHTS_CHECKSUM_MISMATCH']);
  assert.equal(info.fallbackShown, info.meshes, 'every mesh keeps its fallback material');
  const logs = await page.evaluate(() => harness.logs);
  assert.ok(logs.some((l) => l.includes('WEIGHTS_CHECKSUM_MISMATCH') && l.includes('fallback')), logs.join('\n'));
});

test('a plain glTF loads unchanged with the plugin registered', async () => {
  const info = await page.evaluate((u) => harness.load(u), '/samples/capture/mesh.glb');
  assert.equal(info.status, 'none');
  assert.ok(info.meshes > 0);
  assert.deepEqual(page.errors, []);
});
