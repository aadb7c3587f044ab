// Browser side of the tests: loads assets through GLTFLoader + DNRGLTFPlugin into a real
// three.js WebGLRenderer and reads the neural layer back, 8-bit, base64.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { DNRGLTFPlugin, DNRNeuralLayer } from '/src/index.js';

const params = new URLSearchParams(location.search);
const logs = [];
for (const level of ['info', 'warn', 'error']) {
  const orig = console[level].bind(console);
  console[level] = (...a) => { logs.push(`${level}: ${a.join(' ')}`); orig(...a); };
}

const renderer = new THREE.WebGLRenderer({ preserveDrawingBuffer: true, alpha: true, antialias: false });
renderer.setPixelRatio(1);
document.body.appendChild(renderer.domElement);
const layer = new DNRNeuralLayer(renderer, { forceCPU: params.has('cpu'), debug: true });
const scene = new THREE.Scene();
let current = null;

function b64(u8) {
  let s = '';
  for (let i = 0; i < u8.length; i += 0x8000) s += String.fromCharCode(...u8.subarray(i, i + 0x8000));
  return btoa(s);
}

/** floor(255 * clamp(c, 0, 1) + 0.5), non-finite 0: the spec's 8-bit rounding. */
function quantize(f) {
  const out = new Uint8Array(f.length);
  for (let i = 0; i < f.length; i++) {
    const c = f[i];
    out[i] = Number.isFinite(c) ? Math.floor(255 * Math.min(1, Math.max(0, c)) + 0.5) : 0;
  }
  return out;
}

/** A three.js camera from pinhole intrinsics and a column-major camera-to-world matrix. */
function makeCamera(k, near = 0.01, far = 1000) {
  const { fx, fy, cx, cy, width: w, height: h } = k;
  const cam = new THREE.PerspectiveCamera();
  cam.matrixAutoUpdate = false;
  cam.matrixWorld.fromArray(k.camToWorld);
  cam.matrixWorldInverse.copy(cam.matrixWorld).invert();
  cam.projectionMatrix.set(
    2 * fx / w, 0, 1 - 2 * cx / w, 0,
    0, 2 * fy / h, 2 * cy / h - 1, 0,
    0, 0, -(far + near) / (far - near), -2 * far * near / (far - near),
    0, 0, -1, 0,
  );
  cam.projectionMatrixInverse.copy(cam.projectionMatrix).invert();
  return cam;
}

window.harness = {
  logs,
  path: () => layer.path,
  async load(url) {
    if (current) { scene.remove(current.scene); if (current.userData.dnr) layer.detach(current.userData.dnr); }
    const loader = new GLTFLoader();
    loader.register((parser) => new DNRGLTFPlugin(parser, layer));
    const t0 = performance.now();
    const gltf = await loader.loadAsync(url);
    scene.add(gltf.scene);
    current = gltf;
    const status = gltf.userData.dnr ? await gltf.userData.dnr.ready : 'none';
    return {
      status, ms: performance.now() - t0,
      report: gltf.userData.dnr?.report ?? null,
      meshes: (() => { let n = 0; gltf.scene.traverse((o) => { if (o.isMesh) n++; }); return n; })(),
      fallbackShown: (() => { let n = 0; gltf.scene.traverse((o) => { if (o.isMesh && o.material?.map) n++; }); return n; })(),
    };
  },
  /** The GPU layer for camera `k` ({fx, fy, cx, cy, width, height, camToWorld}). */
  gpu(k) {
    const cam = makeCamera(k);
    const passes = layer.computeLayer(scene, cam, k.width, k.height);
    return { passes, rgba: b64(quantize(layer.readLayer())) };
  },
  /** Lowers the largest G-buffer side the layer allows (a GPU with smaller limits). */
  limitTargets(n) {
    layer.maxTargetSize = Math.min(layer.maxTargetSize, n);
    layer.passes = null;
    return layer.maxTargetSize;
  },
  /** The G-buffer's attachment `i` after the last frame, rows bottom first. */
  gbuf(i) {
    const [w, h] = layer.frameSize;
    const out = new Float32Array(w * h * 4);
    renderer.readRenderTargetPixels(layer.gbuf, 0, 0, w, h, out, undefined, i);
    return Array.from(out);
  },
  /**
   * The GPU layer beside the CPU runtime's shading of the GPU's own G-buffer (single-primitive
   * assets: every covered pixel is scene primitive 0): the networks alone, without the
   * rasterisers' differences.
   */
  async gpuAndShade(k) {
    const g = this.gpu(k);
    const [w, h] = layer.frameSize;
    const g0 = this.gbuf(0);
    const g1 = this.gbuf(1);
    const n = w * h;
    const coverage = new Float32Array(n);
    const prim = new Uint32Array(n);
    const uv = new Float32Array(2 * n);
    const viewDir = new Float32Array(3 * n);
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w; x++) {
        const s = ((h - 1 - y) * w + x) * 4;
        const i = y * w + x;
        if (g0[s + 3] > 0.5) {
          coverage[i] = 1;
          uv[2 * i] = g0[s]; uv[2 * i + 1] = g0[s + 1];
          viewDir.set([g1[s], g1[s + 1], g1[s + 2]], 3 * i);
        }
      }
    }
    const a = layer.assets[layer.assets.length - 1];
    const r = await layer.decoder.request({ op: 'shade', asset: a.cpuAsset, width: w, height: h, coverage, prim, uv, viewDir });
    return { gpu: g.rgba, shade: b64(quantize(r.rgba)) };
  },
  async cpu(k) {
    const cam = makeCamera(k);
    return { rgba: b64(quantize(await layer.renderCPU(cam, k.width, k.height))) };
  },
  /** Mean milliseconds of `frames` frames of the layer (G-buffer, networks, composite). */
  time(k, frames) {
    const cam = makeCamera(k);
    const gl = renderer.getContext();
    const px = new Float32Array(4);
    layer.computeLayer(scene, cam, k.width, k.height);
    renderer.readRenderTargetPixels(layer.nTarget, 0, 0, 1, 1, px);
    const t0 = performance.now();
    for (let i = 0; i < frames; i++) {
      layer.computeLayer(scene, cam, k.width, k.height);
      renderer.readRenderTargetPixels(layer.nTarget, 0, 0, 1, 1, px); // waits for the GPU
    }
    void gl;
    return { ms: (performance.now() - t0) / frames, cost: layer.cost(k.width, k.height) };
  },
};
window.harnessReady = true;
