// A small static server for the example viewer and the browser tests (127.0.0.1 only).
//   node scripts/serve.mjs [--port N] [--open-example]
// Serves viewers/three/ at /, the repository's samples/ at /samples/ and, when DNR_OUT is
// set, that folder at /out/ (test assets).
import { createServer } from 'node:http';
import { readFile, stat } from 'node:fs/promises';
import { extname, join, normalize, resolve, sep } from 'node:path';
import { fileURLToPath } from 'node:url';

const here = resolve(fileURLToPath(new URL('..', import.meta.url)));
const repo = resolve(here, '..', '..');

const TYPES = {
  '.html': 'text/html; charset=utf-8', '.js': 'text/javascript', '.mjs': 'text/javascript',
  '.json': 'application/json', '.wasm': 'application/wasm', '.glb': 'model/gltf-binary',
  '.gltf': 'model/gltf+json', '.bin': 'application/octet-stream', '.png': 'image/png',
  '.f32': 'application/octet-stream', '.css': 'text/css',
};

function mounts() {
  const m = [['/samples/', join(repo, 'samples')]];
  if (process.env.DNR_OUT) m.push(['/out/', resolve(process.env.DNR_OUT)]);
  m.push(['/', here]);
  return m;
}

/** Starts the server; resolves to { url, close }. */
export async function serve(port = 0) {
  const table = mounts();
  const server = createServer(async (req, res) => {
    try {
      const path = decodeURIComponent(new URL(req.url, 'http://localhost').pathname);
      const [prefix, dir] = table.find(([p]) => path.startsWith(p));
      let file = normalize(join(dir, path.slice(prefix.length)));
      if (file !== dir && !file.startsWith(dir + sep)) throw Object.assign(new Error('outside'), { code: 'ENOENT' });
      if ((await stat(file)).isDirectory()) file = join(file, 'index.html');
      const body = await readFile(file);
      res.writeHead(200, { 'content-type': TYPES[extname(file)] || 'application/octet-stream', 'cache-control': 'no-store' });
      res.end(body);
    } catch (e) {
      res.writeHead(e.code === 'ENOENT' ? 404 : 500, { 'content-type': 'text/plain' });
      res.end(String(e.message));
    }
  });
  await new Promise((ok) => server.listen(port, '127.0.0.1', ok));
  const url = `http://127.0.0.1:${server.address().port}`;
  return { url, close: () => new Promise((ok) => server.close(ok)) };
}

if (process.argv[1] && resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
  const i = process.argv.indexOf('--port');
  const port = i > 0 ? Number(process.argv[i + 1]) : 8080;
  const { url } = await serve(port);
  console.log(`serving viewers/three at ${url}`);
  console.log(`example viewer: ${url}/example/  (open or drop a .glb; ?asset=URL loads one)`);
}
