// Node side helpers of the browser tests: PNG decoding, the spec's comparison, chromium.
import { inflateSync } from 'node:zlib';
import { readFileSync, existsSync } from 'node:fs';
import { delimiter, join } from 'node:path';
import { chromium } from 'playwright-core';

/** RGBA8 pixels of an 8-bit RGBA or RGB PNG (non-interlaced). */
export function decodePng(buf) {
  if (buf.readUInt32BE(0) !== 0x89504e47) throw new Error('not a PNG');
  let pos = 8;
  let width = 0;
  let height = 0;
  let ctype = 0;
  const idat = [];
  while (pos < buf.length) {
    const len = buf.readUInt32BE(pos);
    const type = buf.toString('latin1', pos + 4, pos + 8);
    const data = buf.subarray(pos + 8, pos + 8 + len);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      if (data[8] !== 8 || data[12] !== 0) throw new Error('only 8-bit non-interlaced PNGs');
      ctype = data[9];
    } else if (type === 'IDAT') idat.push(data);
    else if (type === 'IEND') break;
    pos += 12 + len;
  }
  const bpp = { 6: 4, 2: 3 }[ctype];
  if (!bpp) throw new Error(`PNG colour type ${ctype} not supported`);
  const raw = inflateSync(Buffer.concat(idat));
  const stride = width * bpp;
  const px = Buffer.alloc(height * stride);
  for (let y = 0; y < height; y++) {
    const f = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let x = 0; x < stride; x++) {
      const a = x >= bpp ? px[y * stride + x - bpp] : 0;
      const b = y > 0 ? px[(y - 1) * stride + x] : 0;
      const c = x >= bpp && y > 0 ? px[(y - 1) * stride + x - bpp] : 0;
      let v = line[x];
      if (f === 1) v += a;
      else if (f === 2) v += b;
      else if (f === 3) v += (a + b) >> 1;
      else if (f === 4) {
        const p = a + b - c;
        const pa = Math.abs(p - a);
        const pb = Math.abs(p - b);
        const pc = Math.abs(p - c);
        v += pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      }
      px[y * stride + x] = v & 255;
    }
  }
  if (bpp === 4) return { width, height, rgba: new Uint8Array(px) };
  const rgba = new Uint8Array(width * height * 4);
  for (let i = 0; i < width * height; i++) {
    rgba.set(px.subarray(i * 3, i * 3 + 3), i * 4);
    rgba[i * 4 + 3] = 255;
  }
  return { width, height, rgba };
}

/**
 * The spec's comparison (Conformance Samples): alpha at every pixel, colour where the
 * reference alpha is above 0; `within` = fraction of pixels within 2/255 in every compared
 * channel, `mean` = mean absolute difference over the compared channels (of 255).
 */
export function compare(reference, out) {
  if (reference.length !== out.length) throw new Error(`sizes differ: ${reference.length} vs ${out.length}`);
  let ok = 0;
  let sum = 0;
  let count = 0;
  let worst = 0;
  const n = reference.length / 4;
  for (let i = 0; i < n; i++) {
    const r = i * 4;
    const ks = reference[r + 3] > 0 ? [0, 1, 2, 3] : [3];
    let w = 0;
    for (const k of ks) {
      const d = Math.abs(reference[r + k] - out[r + k]);
      w = Math.max(w, d);
      sum += d;
      count++;
    }
    worst = Math.max(worst, w);
    if (w <= 2) ok++;
  }
  const within = ok / n;
  const mean = sum / Math.max(1, count);
  return { within, mean, worst, pass: within >= 0.995 && mean <= 0.5 };
}

export function fromB64(s) {
  return new Uint8Array(Buffer.from(s, 'base64'));
}

/** $CHROMIUM, or the Debian chromium on the PATH (scripts/setup.sh installs it). */
export function chromiumPath() {
  const onPath = (process.env.PATH || '')
    .split(delimiter)
    .filter(Boolean)
    .flatMap((dir) => ['chromium', 'chromium-browser'].map((name) => join(dir, name)));
  const candidates = [process.env.CHROMIUM, ...onPath].filter(Boolean);
  const found = candidates.find((p) => existsSync(p));
  if (!found) throw new Error('chromium not found: run `bash scripts/setup.sh` (apt-get install chromium) or set CHROMIUM');
  return found;
}

/** Headless chromium with software WebGL2 (SwiftShader through ANGLE). */
export async function launch() {
  return chromium.launch({
    executablePath: chromiumPath(),
    headless: true,
    args: ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist', '--no-sandbox'],
  });
}

/** Opens the harness page and waits until it is ready. */
export async function openHarness(browser, base, query = '') {
  const page = await browser.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('console', (m) => { if (process.env.DNR_TEST_VERBOSE) console.log(`[page] ${m.text()}`); });
  await page.goto(`${base}/test/pages/harness.html${query}`);
  await page.waitForFunction(() => window.harnessReady === true, null, { timeout: 60000 });
  page.errors = errors;
  return page;
}

/** Camera of `dnr render --look-at E,T --fov F --size WxH` (dnr_runtime Camera::look_at). */
export function lookAt(eye, target, fovY, w, h) {
  const sub = (a, b) => a.map((v, i) => v - b[i]);
  const norm = (a) => { const l = Math.hypot(...a); return a.map((v) => v / l); };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const fwd = norm(sub(target, eye));
  let up = [0, 1, 0];
  if (Math.hypot(...cross(fwd, up)) ** 2 < 1e-12) up = [0, 0, 1];
  const z = fwd.map((v) => -v);
  const x = norm(cross(up, z));
  const y = cross(z, x);
  const f = 0.5 * h / Math.tan(0.5 * fovY * Math.PI / 180);
  return { fx: f, fy: f, cx: w / 2, cy: h / 2, width: w, height: h, camToWorld: [...x, 0, ...y, 0, ...z, 0, ...eye, 1] };
}

export const readJson = (p) => JSON.parse(readFileSync(p, 'utf8'));

/** A copy of a GLB whose JSON chunk `edit(json)` changed in place (the BIN chunk as it was). */
export function editGlbJson(glb, edit) {
  const jsonLen = glb.readUInt32LE(12);
  const json = JSON.parse(glb.toString('utf8', 20, 20 + jsonLen));
  edit(json);
  let text = Buffer.from(JSON.stringify(json), 'utf8');
  text = Buffer.concat([text, Buffer.alloc((4 - (text.length % 4)) % 4, 0x20)]);
  const rest = glb.subarray(20 + jsonLen);
  const header = Buffer.alloc(20);
  header.write('glTF', 0, 'latin1');
  header.writeUInt32LE(2, 4);
  header.writeUInt32LE(20 + text.length + rest.length, 8);
  header.writeUInt32LE(text.length, 12);
  header.write('JSON', 16, 'latin1');
  return Buffer.concat([header, text, rest]);
}
