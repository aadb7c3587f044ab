// Frame time of the plugin's neural layer against the Rust runtime, on this machine.
//
//   node scripts/bench.mjs ASSET [--sizes 256,512] [--frames 10] [--reps 5]
//        [--tflops 5] [--gbs 192] [--gtexels 24] [--markdown FILE]
//
// Times the layer (G-buffer, features, network; read back one pixel to wait for the GPU) in
// headless chromium with SwiftShader, a CPU emulation of WebGL2: a floor, not a GPU figure.
// Beside it, `dnr bench render` of the same asset and camera in the same run (the CPU
// runtime). Then the network's passes, texture fetches and multiply-adds per frame, and from
// them an estimate for a GPU of the given FP32 rate (TFLOP/s), memory bandwidth (GB/s) and
// RGBA32F fetch rate (Gtexel/s): the largest of the three bounds plus 5 us a pass.
// With --markdown, the tables replace the section `dnr-three bench NAME` of FILE (between its
// BEGIN and END lines), or FILE is written when it has no such section.
import { execFileSync } from 'node:child_process';
import { existsSync, readFileSync, writeFileSync } from 'node:fs';
import { cpus, loadavg } from 'node:os';
import { basename, dirname, join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { serve } from './serve.mjs';
import { launch, openHarness, lookAt } from '../test/lib.mjs';

const here = resolve(fileURLToPath(new URL('..', import.meta.url)));
const repo = resolve(here, '..', '..');

function args(argv) {
  const o = { sizes: [256, 512], frames: 10, reps: 5, tflops: 5, gbs: 192, gtexels: 24, markdown: null, asset: null };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const v = () => {
      if (i + 1 >= argv.length) throw new Error(`${a} needs a value`);
      return argv[++i];
    };
    if (a === '--sizes') o.sizes = v().split(',').map(Number);
    else if (['--frames', '--reps', '--tflops', '--gbs', '--gtexels'].includes(a)) o[a.slice(2)] = Number(v());
    else if (a === '--markdown') o.markdown = v();
    else if (a.startsWith('--')) throw new Error(`unknown option ${a}`);
    else o.asset = resolve(a);
  }
  if (!o.asset || !existsSync(o.asset)) throw new Error('usage: node scripts/bench.mjs ASSET [options] (the asset must exist)');
  if (o.sizes.some((s) => !(s > 0 && s <= 4096))) throw new Error('--sizes: sizes from 1 to 4096');
  return o;
}

/** `dnr bench render`'s minimum ms per frame for each size (its first table). */
function cpuTimes(asset, sizes, reps) {
  const bin = ['release', 'debug'].map((p) => join(repo, 'target', p, 'dnr')).find(existsSync);
  if (!bin) throw new Error('dnr is not built: cargo build --release -p dnr-cli');
  const text = execFileSync(bin, ['bench', 'render', asset, '--sizes', sizes.join(','), '--reps', String(reps)], { encoding: 'utf8' });
  const ms = {};
  for (const line of text.split('\n')) {
    const cells = line.split('|').map((c) => c.trim()).filter(Boolean);
    if (cells.length >= 2 && sizes.includes(Number(cells[0]))) ms[Number(cells[0])] = Number(cells[1]);
  }
  for (const s of sizes) if (!(ms[s] > 0)) throw new Error(`no time for ${s} in dnr bench render's output:\n${text}`);
  return ms;
}

function section(name, body, file) {
  const begin = `<!-- BEGIN ${name} -->`;
  const end = `<!-- END ${name} -->`;
  const block = `${begin}\n${body}${end}`;
  const old = existsSync(file) ? readFileSync(file, 'utf8') : '';
  const i = old.indexOf(begin);
  const j = old.indexOf(end);
  writeFileSync(file, i >= 0 && j > i ? old.slice(0, i) + block + old.slice(j + end.length) : `${block}\n`);
}

const o = args(process.argv.slice(2));
process.env.DNR_OUT = dirname(o.asset);
// The camera of `dnr bench render` (its first position on the circle).
const camera = (s) => lookAt([0, 1.2, 3.4], [0, 0, 0], 40, s, s);
const load = loadavg()[0];
const server = await serve(0);
const browser = await launch();
const gpu = {};
let cost = {};
try {
  const page = await openHarness(browser, server.url);
  const info = await page.evaluate((u) => harness.load(u), `/out/${basename(o.asset)}`);
  if (info.status !== 'gpu') throw new Error(`the plugin did not take the GPU path: ${JSON.stringify(info)}`);
  for (const s of o.sizes) {
    let best = Infinity;
    for (let r = 0; r < o.reps; r++) {
      const t = await page.evaluate(([k, n]) => harness.time(k, n), [camera(s), o.frames]);
      best = Math.min(best, t.ms);
      cost[s] = t.cost;
    }
    gpu[s] = best;
  }
} finally {
  await browser.close();
  await server.close();
}
const cpu = cpuTimes(o.asset, o.sizes, o.reps);

const rows = [];
rows.push('| size | plugin, SwiftShader (ms, min) | dnr render, CPU (ms, min) | ratio |');
rows.push('| ---: | ---: | ---: | ---: |');
for (const s of o.sizes) rows.push(`| ${s} | ${gpu[s].toFixed(1)} | ${cpu[s].toFixed(1)} | ${(gpu[s] / cpu[s]).toFixed(2)} |`);
rows.push('');
rows.push(`Network per frame, and the estimate for a GPU of ${o.tflops} TFLOP/s FP32, ${o.gbs} GB/s and ${o.gtexels} Gtexel/s of RGBA32F fetches (largest bound + 5 us a pass):`);
rows.push('');
rows.push('| size | renderer | passes | fetches | fetches / pixel | GMAC | MB written | estimate (ms) |');
rows.push('| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |');
for (const s of o.sizes) {
  for (const c of cost[s]) {
    const compute = 2 * c.macs / (o.tflops * 1e12);
    const fetch = c.fetches / (o.gtexels * 1e9);
    const memory = (c.bytes + c.fetches * 16 * 0.1) / (o.gbs * 1e9); // writes, and a 90 % cache hit rate on reads
    const ms = 1e3 * (Math.max(compute, fetch, memory) + c.passes * 5e-6);
    rows.push(`| ${s} | ${c.renderer} | ${c.passes} | ${(c.fetches / 1e6).toFixed(1)} M | ${(c.fetches / (s * s)).toFixed(0)} | ${(c.macs / 1e9).toFixed(2)} | ${(c.bytes / 1e6).toFixed(1)} | ${ms.toFixed(2)} |`);
  }
}
const body = `${rows.join('\n')}\n`;
process.stdout.write(body);
if (o.markdown) {
  const stamp = `${new Date().toISOString().slice(0, 10)}, commit \`${execFileSync('git', ['describe', '--always', '--dirty'], { cwd: repo, encoding: 'utf8' }).trim()}\`, ${cpus()[0].model}, ${cpus().length} vCPUs, load average ${load.toFixed(1)} at the start; asset \`${basename(o.asset)}\`, ${o.frames} frames x ${o.reps} repetitions\n\n`;
  section(`dnr-three bench ${basename(o.asset)}`, stamp + body, o.markdown);
  console.error(`wrote the tables to ${o.markdown}`);
}
