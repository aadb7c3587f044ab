// Example viewer: open or drop a .glb, orbit, toggle neural / fallback, frame time shown.
// URL parameters (all optional): asset=URL, eye=x,y,z, target=x,y,z, fov=deg,
// size=WxH (fixed canvas size), bg=rrggbb, neural=0, cpu (force the CPU path), ui=0.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { DNRGLTFPlugin, DNRNeuralLayer } from '../src/index.js';

const q = new URLSearchParams(location.search);
const vec = (s, d) => (s ? s.split(',').map(Number) : d);
const size = q.get('size') ? q.get('size').split('x').map(Number) : null;
const bg = new THREE.Color(`#${q.get('bg') || 'ffffff'}`);
if (q.get('ui') === '0') document.getElementById('bar').style.display = 'none';

const renderer = new THREE.WebGLRenderer({ antialias: !size, preserveDrawingBuffer: true });
renderer.setPixelRatio(size ? 1 : window.devicePixelRatio);
document.body.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = bg;
const camera = new THREE.PerspectiveCamera(Number(q.get('fov') || 40), 1, 0.01, 1000);
camera.position.fromArray(vec(q.get('eye'), [2.6, 1.2, 2.4]));
const controls = new OrbitControls(camera, renderer.domElement);
controls.target.fromArray(vec(q.get('target'), [0, 0, 0]));
controls.update();

const layer = new DNRNeuralLayer(renderer, { forceCPU: q.has('cpu') });
const statusEl = document.getElementById('status');
const timeEl = document.getElementById('time');
const neuralEl = document.getElementById('neural');
let current = null;

function resize() {
  const [w, h] = size || [window.innerWidth, window.innerHeight];
  renderer.setSize(w, h, !size);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

async function open(url, name = url) {
  if (current) {
    scene.remove(current.scene);
    if (current.userData.dnr) layer.detach(current.userData.dnr);
  }
  statusEl.textContent = `loading ${name}`;
  const loader = new GLTFLoader();
  loader.register((parser) => new DNRGLTFPlugin(parser, layer));
  const gltf = await loader.loadAsync(url);
  current = gltf;
  scene.add(gltf.scene);
  statusEl.textContent = `${name}: fallback (decoding)`;
  const status = gltf.userData.dnr ? await gltf.userData.dnr.ready : 'no neural layer';
  statusEl.textContent = `${name}: ${status === 'gpu' ? 'neural (GPU)' : status === 'cpu' ? 'neural (wasm CPU)' : status}`;
  return status;
}

neuralEl.checked = q.get('neural') !== '0';
neuralEl.addEventListener('change', () => layer.setEnabled(neuralEl.checked));
document.getElementById('file').addEventListener('change', (e) => {
  const f = e.target.files[0];
  if (f) open(URL.createObjectURL(f), f.name);
});
const drop = document.getElementById('drop');
window.addEventListener('dragover', (e) => { e.preventDefault(); drop.style.display = 'flex'; });
window.addEventListener('dragleave', () => { drop.style.display = 'none'; });
window.addEventListener('drop', (e) => {
  e.preventDefault();
  drop.style.display = 'none';
  const f = e.dataTransfer.files[0];
  if (f) open(URL.createObjectURL(f), f.name);
});

// Frame time: the interval between animation frames (the GPU's work included, as the
// browser paces frames to it), averaged.
let avg = 0;
let last = 0;
renderer.setAnimationLoop((now) => {
  controls.update();
  renderer.render(scene, camera);
  layer.render(scene, camera);
  if (last) avg = avg ? 0.9 * avg + 0.1 * (now - last) : now - last;
  last = now;
  const mode = !current?.userData.dnr ? '' : neuralEl.checked ? ` ${layer.path}` : ' fallback';
  timeEl.textContent = `${avg.toFixed(1)} ms/frame${mode}`;
});

window.viewer = {
  layer,
  ready: q.get('asset') ? open(q.get('asset')).then((s) => { layer.setEnabled(neuralEl.checked); return s; }) : Promise.resolve('none'),
  setNeural(on) { neuralEl.checked = on; layer.setEnabled(on); },
};
