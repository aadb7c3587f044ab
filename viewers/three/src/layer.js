// DNRNeuralLayer: draws the neural appearance of the assets DNRGLTFPlugin loaded, each frame,
// after the application's own `renderer.render(scene, camera)`.
//
// Frame (GPU path): a G-buffer pass through three's WebGLRenderer (the whole scene, bound
// primitives writing uv / neural texture / renderer / local view direction, every other
// surface marked "core"), one more at s times the frame's width and height for each
// `supersample` s > 1 in use (the subsamples), then each network's fixed list of passes,
// the composite of the renderers into the neural layer N (spec, Compositing Several
// Renderers), and N drawn over the canvas with straight-alpha source-over. Render targets
// are allocated once per frame size. Without float render targets, the wasm CPU renderer
// draws N instead.

import {
  BufferGeometry, Float32BufferAttribute, Mesh, OrthographicCamera, Scene, ShaderMaterial,
  GLSL3, DoubleSide, FrontSide, BackSide, NormalBlending, Vector2, Vector3, Matrix4, Color,
  WebGLRenderTarget, FloatType, RGBAFormat, NearestFilter, DataTexture,
} from 'three';
import { AssetGPU, floatTarget, passMaterial } from './network.js';
import {
  compositeShader, coverageShader, DISPLAY_SHADER, GBUFFER_VERTEX, GBUFFER_FRAGMENT,
} from './glsl.js';
import { getDecoder } from './decoder.js';

const TEXCOORD_ATTRIBUTES = ['uv', 'uv1', 'uv2', 'uv3'];

/**
 * Checks what the GPU path needs: WebGL2, EXT_color_buffer_float and a complete RGBA32F
 * framebuffer. Returns null when it can run, else the reason.
 */
export function probeGPU(renderer) {
  const gl = renderer.getContext();
  if (typeof WebGL2RenderingContext === 'undefined' || !(gl instanceof WebGL2RenderingContext)) {
    return 'no WebGL2 context';
  }
  if (!gl.getExtension('EXT_color_buffer_float')) return 'EXT_color_buffer_float is not supported';
  const tex = gl.createTexture();
  const fb = gl.createFramebuffer();
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, 4, 4, 0, gl.RGBA, gl.FLOAT, null);
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
  const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.deleteFramebuffer(fb);
  gl.deleteTexture(tex);
  renderer.resetState();
  if (status !== gl.FRAMEBUFFER_COMPLETE) return `an RGBA32F framebuffer is incomplete (0x${status.toString(16)})`;
  if (gl.getParameter(gl.MAX_DRAW_BUFFERS) < 2) return 'fewer than 2 draw buffers';
  return null;
}

/** G-buffer render target: two RGBA32F attachments and a depth buffer. */
function gbufferTarget(width, height) {
  return new WebGLRenderTarget(width, height, {
    count: 2, type: FloatType, format: RGBAFormat, minFilter: NearestFilter, magFilter: NearestFilter,
    depthBuffer: true, generateMipmaps: false,
  });
}

function gbufferMaterial(side, uniforms, defines = {}) {
  return new ShaderMaterial({
    glslVersion: GLSL3, vertexShader: GBUFFER_VERTEX, fragmentShader: GBUFFER_FRAGMENT,
    uniforms, defines, side,
  });
}

/** Intrinsics and pose of a three.js perspective camera for a `width x height` frame. */
export function pinholeOf(camera, width, height) {
  const e = camera.projectionMatrix.elements;
  return {
    fx: e[0] * width / 2, fy: e[5] * height / 2,
    cx: (1 - e[8]) * width / 2, cy: (1 + e[9]) * height / 2,
  };
}

/**
 * A non-indexed copy of a triangle geometry whose every vertex also carries its triangle's
 * three local positions (aP0..aP2) and texture coordinates (aT0..aT2), for the G-buffer's
 * exact evaluation at pixel centres.
 */
function exactGeometry(geometry, uvName) {
  const pos = geometry.getAttribute('position');
  const uv = uvName ? geometry.getAttribute(uvName) : null;
  const index = geometry.getIndex();
  const count = index ? index.count : pos.count;
  const tris = Math.floor(count / 3);
  const P = new Float32Array(tris * 9);
  const T = new Float32Array(tris * 6);
  for (let t = 0; t < tris; t++) {
    for (let k = 0; k < 3; k++) {
      const v = index ? index.getX(3 * t + k) : 3 * t + k;
      P.set([pos.getX(v), pos.getY(v), pos.getZ(v)], 9 * t + 3 * k);
      if (uv) T.set([uv.getX(v), uv.getY(v)], 6 * t + 2 * k);
    }
  }
  const g = new BufferGeometry();
  g.setAttribute('position', new Float32BufferAttribute(P, 3));
  for (let k = 0; k < 3; k++) {
    const p = new Float32Array(tris * 9);
    const q = new Float32Array(tris * 6);
    for (let t = 0; t < tris; t++) {
      for (let j = 0; j < 3; j++) {
        p.set(P.subarray(9 * t + 3 * k, 9 * t + 3 * k + 3), 9 * t + 3 * j);
        q.set(T.subarray(6 * t + 2 * k, 6 * t + 2 * k + 2), 6 * t + 2 * j);
      }
    }
    g.setAttribute(`aP${k}`, new Float32BufferAttribute(p, 3));
    g.setAttribute(`aT${k}`, new Float32BufferAttribute(q, 2));
  }
  if (uv) g.setAttribute(uvName, new Float32BufferAttribute(T, 2));
  g.boundingSphere = geometry.boundingSphere;
  g.boundingBox = geometry.boundingBox;
  return g;
}

export class DNRNeuralLayer {
  /**
   * @param {import('three').WebGLRenderer} renderer
   * @param {{ debug?: boolean, forceCPU?: boolean, worker?: boolean }} options
   *   debug: print each network's pass list once; forceCPU: draw with the wasm CPU renderer;
   *   worker: decode in a module worker (default true).
   */
  constructor(renderer, { debug = false, forceCPU = false, worker = true } = {}) {
    this.renderer = renderer;
    this.debug = debug;
    this.forceCPU = forceCPU;
    this.enabled = true;
    this.decoder = getDecoder({ worker });
    this.assets = [];
    this.texCount = 0;
    this.rendCount = 0;
    this.frameSize = [0, 0];
    this.passes = null;
    this.gpuProblem = forceCPU ? 'forced' : probeGPU(renderer);
    this.mode = forceCPU ? 'cpu' : (this.gpuProblem ? 'cpu' : 'gpu');
    if (forceCPU) {
      console.info('dnr: CPU path forced; the wasm CPU renderer draws the neural layer');
    } else if (this.gpuProblem) {
      console.info(`dnr: GPU path unavailable (${this.gpuProblem}); the wasm CPU renderer draws the neural layer`);
    }
    const gl = renderer.getContext();
    this.maxSize = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    this.maxLayers = gl.getParameter(gl.MAX_ARRAY_TEXTURE_LAYERS);
    // Largest side of a G-buffer (colour textures, depth renderbuffer, viewport); a subsample
    // G-buffer beyond it falls back to pixel-centre features.
    const vp = gl.getParameter(gl.MAX_VIEWPORT_DIMS);
    this.maxTargetSize = Math.min(this.maxSize, gl.getParameter(gl.MAX_RENDERBUFFER_SIZE), vp[0], vp[1]);
    this.fine = new Map();
    this.quadScene = new Scene();
    const geo = new BufferGeometry();
    geo.setAttribute('position', new Float32BufferAttribute([-1, -1, 0, 3, -1, 0, -1, 3, 0], 3));
    this.quad = new Mesh(geo);
    this.quad.frustumCulled = false;
    this.quadScene.add(this.quad);
    this.quadCamera = new OrthographicCamera();
    this.shared = { uOrtho: { value: false }, uCamDir: { value: new Vector3() } };
    const core = { ...this.shared, uTex: { value: 0 }, uRid: { value: -1 } };
    this.coreMaterials = {
      [FrontSide]: gbufferMaterial(FrontSide, core),
      [BackSide]: gbufferMaterial(BackSide, core),
      [DoubleSide]: gbufferMaterial(DoubleSide, core),
    };
    this.hiddenMaterial = new ShaderMaterial({ colorWrite: false, side: DoubleSide });
    this.display = passMaterial(DISPLAY_SHADER, { uN: { value: null }, uFrame: { value: [0, 0] } });
    this.display.transparent = true;
    this.display.blending = NormalBlending;
    this.display.premultipliedAlpha = false;
    this.stats = { frames: 0, lastMs: 0 };
  }

  /** How the layer draws: 'gpu', 'cpu' or, with nothing to draw, still one of them. */
  get path() { return this.mode; }

  /**
   * Takes over the bound meshes of a decoded asset (called by DNRGLTFPlugin). `bound` lists
   * `{ object, binding }` for every mesh of the loaded scenes with a binding; `root` is the
   * glTF's scene (the CPU renderer draws in its frame).
   */
  async attach(handle, decoded) {
    const entry = { handle, decoded, root: handle.root, bound: handle.bound, gpu: null, cpuAsset: decoded.asset };
    if (this.mode === 'gpu') {
      try {
        entry.gpu = new AssetGPU(decoded, {
          texBase: this.texCount, rendBase: this.rendCount, maxSize: this.maxSize, maxLayers: this.maxLayers,
        });
        this.texCount += decoded.desc.textures.length;
        this.rendCount += decoded.desc.renderers.length;
      } catch (e) {
        console.info(`dnr: ${handle.name}: GPU path unavailable (${e.message}); the wasm CPU renderer draws the neural layer`);
        entry.gpu = null;
      }
    }
    for (const b of entry.bound) {
      const attr = TEXCOORD_ATTRIBUTES[b.binding.texCoord];
      const hasUv = attr !== undefined && b.object.geometry.getAttribute(attr) !== undefined;
      const defines = {};
      if (hasUv) {
        defines.DNR_UV = attr;
        if (attr !== 'uv') defines[`USE_${attr.toUpperCase()}`] = '';
      }
      b.fallback = b.object.material;
      if (entry.gpu) {
        const o = b.object;
        // Exact uv and view direction at pixel centres (see GBUFFER_FRAGMENT) for rigid
        // meshes; skinned, morphed and instanced ones use the interpolated attributes.
        const rigid = !o.isSkinnedMesh && !o.isInstancedMesh && !o.isBatchedMesh && !o.geometry.morphAttributes.position;
        if (rigid) {
          b.exactGeometry = exactGeometry(o.geometry, hasUv ? attr : null);
          defines.DNR_EXACT = '';
        }
        b.gbuffer = gbufferMaterial(DoubleSide, {
          ...this.shared,
          uTex: { value: hasUv ? entry.gpu.texBase + b.binding.neuralTexture : -1 },
          uRid: { value: entry.gpu.rendBase + b.binding.renderer + 1 },
          uInvMVP: { value: new Matrix4() },
          uViewport: { value: [1, 1] },
        }, defines);
      }
    }
    this.assets.push(entry);
    this.passes = null;
    this._showNeural(entry, this.enabled);
    return entry.gpu ? 'gpu' : 'cpu';
  }

  /** Stops drawing an asset (the handle from `gltf.userData.dnr`) and frees its GPU resources. */
  detach(handle) {
    const i = this.assets.findIndex((a) => a.handle === handle);
    if (i < 0) return;
    const [a] = this.assets.splice(i, 1);
    this._showNeural(a, false);
    a.gpu?.dispose();
    a.cpuTexture?.dispose();
    for (const b of a.bound) { b.gbuffer?.dispose(); b.exactGeometry?.dispose(); }
    this.decoder.request({ op: 'drop', asset: a.cpuAsset }).catch(() => {});
    this.passes = null;
    this._disposeFine();
    this.frameSize = [0, 0];
    if (this.assets.length === 0) { this.texCount = 0; this.rendCount = 0; }
  }

  /** Neural layer on (bound meshes drawn by the layer) or off (fallback materials). */
  setEnabled(on) {
    this.enabled = on;
    for (const a of this.assets) this._showNeural(a, on);
  }

  _showNeural(entry, on) {
    for (const b of entry.bound) b.object.material = on ? this.hiddenMaterial : b.fallback;
  }

  _disposeFine() {
    for (const f of this.fine.values()) if (f.target !== this.gbuf) f.target.dispose();
    this.fine.clear();
  }

  /**
   * The subsample G-buffers `{ target, s }` of the distinct `supersample` factors s > 1 of
   * `nets`, each s times the frame's width and height. One that exceeds the GPU's limits
   * maps to the frame's own G-buffer with s = 1: its renderers get pixel-centre features,
   * as a reader of revision 1.2 gives them (spec, Versioning and Unknown Values).
   */
  _ensureFine(nets, width, height) {
    this._disposeFine();
    const factors = [...new Set(nets.map((n) => n.supersample).filter((s) => s > 1))].sort((a, b) => a - b);
    for (const s of factors) {
      if (s * width > this.maxTargetSize || s * height > this.maxTargetSize) {
        const ids = nets.filter((n) => n.supersample === s).map((n) => n.global).join(', ');
        console.warn(`dnr: the ${s}x${s} subsample G-buffer of a ${width}x${height} frame (${s * width}x${s * height}) `
          + `exceeds the GPU's ${this.maxTargetSize} limit; renderer ${ids} uses pixel-centre features at this size`);
        this.fine.set(s, { target: this.gbuf, s: 1 });
      } else {
        this.fine.set(s, { target: gbufferTarget(s * width, s * height), s });
      }
    }
  }

  _ensureFrame(width, height) {
    if (this.frameSize[0] === width && this.frameSize[1] === height && this.passes) return;
    this._disposeFine();
    this.gbuf?.dispose();
    this.nTarget?.dispose();
    this.covRows?.dispose();
    this.covFlags?.dispose();
    this.frameSize = [width, height];
    this.gbuf = gbufferTarget(width, height);
    this.nTarget = floatTarget(width, height);
    const nets = [];
    for (const a of this.assets) if (a.gpu) nets.push(...a.gpu.nets);
    for (const n of nets) n.resize(width, height);
    this._ensureFine(nets, width, height);
    const flagGroups = Math.max(1, Math.ceil(this.rendCount / 4));
    this.covRows = floatTarget(flagGroups, height);
    this.covFlags = floatTarget(flagGroups, 1);
    // Per-frame pass list, fixed for this frame size.
    const list = [];
    for (const n of nets) n.passes(list, this.gbuf, this.fine.get(n.supersample));
    const renderers = [];
    for (const n of nets) renderers[n.global] = { present: true, backgroundAlpha: n.backgroundAlpha, net: n };
    for (let i = 0; i < this.rendCount; i++) renderers[i] ||= { present: false };
    if (nets.some((n) => n.backgroundAlpha)) {
      const rows = this.covRowsMat ||= passMaterial(coverageShader(true), { uG0: { value: null }, uFrame: { value: [0, 0] } });
      const cols = this.covColsMat ||= passMaterial(coverageShader(false), { uRows: { value: null }, uFrame: { value: [0, 0] } });
      list.push({ name: 'coverage rows', material: rows, target: this.covRows, set: () => { rows.uniforms.uG0.value = this.gbuf.textures[0]; rows.uniforms.uFrame.value = this.frameSize; } });
      list.push({ name: 'coverage', material: cols, target: this.covFlags, set: () => { cols.uniforms.uRows.value = this.covRows.texture; cols.uniforms.uFrame.value = this.frameSize; } });
    }
    const key = JSON.stringify(renderers.map((r) => [r.present, r.backgroundAlpha]));
    if (this.compositeKey !== key) {
      this.composite?.dispose();
      const uniforms = { uG0: { value: null }, uCov: { value: null }, uFrame: { value: [0, 0] } };
      renderers.forEach((r, i) => { if (r.present) uniforms[`uO${i}`] = { value: null }; });
      this.composite = passMaterial(compositeShader(renderers), uniforms);
      this.compositeKey = key;
    }
    const comp = this.composite;
    list.push({
      name: 'composite', material: comp, target: this.nTarget,
      set: () => {
        comp.uniforms.uG0.value = this.gbuf.textures[0];
        comp.uniforms.uCov.value = this.covFlags.texture;
        comp.uniforms.uFrame.value = this.frameSize;
        renderers.forEach((r, i) => { if (r.present) comp.uniforms[`uO${i}`].value = r.net.output; });
      },
    });
    this.passes = list;
    if (this.debug) {
      for (const n of nets) {
        console.info(`dnr: renderer ${n.global} (${n.constructor.name.replace('GPU', '')}): ${n.passCount} passes per frame`);
      }
      const g = 1 + [...this.fine.values()].filter((f) => f.s > 1).length;
      console.info(`dnr: ${width}x${height}: ${list.length} network and composite passes + ${g} G-buffer pass${g > 1 ? 'es' : ''}: ${list.map((p) => p.name).join(', ')}`);
    }
  }

  /**
   * Draws the G-buffer of `scene` seen by `camera` into this.gbuf and each subsample
   * G-buffer: the same camera and projection, the viewport s times larger, so that fine
   * pixel (s px + i, s py + j) has its centre at image point
   * (px + (i + 0.5) / s, py + (j + 0.5) / s). Returns the number of passes drawn.
   */
  _gbufferPass(scene, camera) {
    const r = this.renderer;
    const bound = new Map();
    const vp = new Matrix4().multiplyMatrices(camera.projectionMatrix, camera.matrixWorldInverse);
    for (const a of this.assets) {
      if (!a.gpu) continue;
      for (const b of a.bound) {
        bound.set(b.object, b);
        const u = b.gbuffer.uniforms;
        u.uInvMVP.value.multiplyMatrices(vp, b.object.matrixWorld).invert();
      }
    }
    const saved = [];
    scene.traverse((o) => {
      if (o.isMesh) {
        const m = o.material;
        const sideOf = (mm) => (mm && mm.side !== undefined ? mm.side : FrontSide);
        const b = bound.get(o);
        saved.push([o, 'material', m]);
        if (b) {
          o.material = b.gbuffer;
          if (b.exactGeometry) {
            saved.push([o, 'geometry', o.geometry]);
            o.geometry = b.exactGeometry;
          }
        }
        else if (Array.isArray(m)) o.material = m.map((mm) => this.coreMaterials[sideOf(mm)]);
        else o.material = this.coreMaterials[sideOf(m)];
      } else if ((o.isLine || o.isPoints || o.isSprite) && o.visible) {
        saved.push([o, 'visible', true]);
        o.visible = false;
      }
    });
    const ortho = !!camera.isOrthographicCamera;
    this.shared.uOrtho.value = ortho;
    camera.getWorldDirection(this.shared.uCamDir.value);
    const background = scene.background;
    const override = scene.overrideMaterial;
    const shadowAuto = r.shadowMap.autoUpdate;
    scene.background = null;
    scene.overrideMaterial = null;
    r.shadowMap.autoUpdate = false;
    r.setClearColor(0x000000, 0);
    const targets = [{ target: this.gbuf, s: 1 }, ...[...this.fine.values()].filter((f) => f.s > 1)];
    for (const { target, s } of targets) {
      const viewport = [s * this.frameSize[0], s * this.frameSize[1]];
      for (const b of bound.values()) b.gbuffer.uniforms.uViewport.value = viewport;
      r.setRenderTarget(target);
      r.clear(true, true, true);
      r.render(scene, camera);
    }
    r.shadowMap.autoUpdate = shadowAuto;
    scene.background = background;
    scene.overrideMaterial = override;
    for (const [o, key, v] of saved) o[key] = v;
    return targets.length;
  }

  /**
   * Computes the neural layer N of `scene` seen by `camera` at `width x height` (GPU path)
   * into an RGBA32F target, without drawing it. Returns the number of passes run.
   */
  computeLayer(scene, camera, width, height) {
    const r = this.renderer;
    const prevTarget = r.getRenderTarget();
    const clearColor = r.getClearColor(new Color());
    const clearAlpha = r.getClearAlpha();
    const autoClear = r.autoClear;
    r.autoClear = false;
    this._ensureFrame(width, height);
    scene.updateMatrixWorld();
    if (camera.parent === null) camera.updateMatrixWorld();
    const gbufferPasses = this._gbufferPass(scene, camera);
    for (const p of this.passes) {
      p.set();
      this.quad.material = p.material;
      r.setRenderTarget(p.target);
      r.render(this.quadScene, this.quadCamera);
    }
    r.setRenderTarget(prevTarget);
    r.setClearColor(clearColor, clearAlpha);
    r.autoClear = autoClear;
    return this.passes.length + gbufferPasses;
  }

  /** The last computed layer: `height * width * 4` floats, rows top first. */
  readLayer() {
    const [w, h] = this.frameSize;
    const out = new Float32Array(w * h * 4);
    this.renderer.readRenderTargetPixels(this.nTarget, 0, 0, w, h, out);
    return out;
  }

  /**
   * Draws the neural layer over what the canvas shows. Call after
   * `renderer.render(scene, camera)`; the frame size is the drawing buffer's.
   */
  render(scene, camera) {
    if (!this.enabled || this.assets.length === 0) return;
    const t0 = performance.now();
    const size = this.renderer.getDrawingBufferSize(this._size ||= new Vector2());
    const [w, h] = [size.x, size.y];
    if (this.mode === 'gpu' && this.assets.every((a) => a.gpu)) {
      this.computeLayer(scene, camera, w, h);
      this._draw(this.nTarget.texture, w, h);
    } else {
      this._renderCPUFrame(camera, w, h);
    }
    this.stats.frames++;
    this.stats.lastMs = performance.now() - t0;
  }

  _draw(texture, w, h) {
    const r = this.renderer;
    const autoClear = r.autoClear;
    r.autoClear = false;
    this.display.uniforms.uN.value = texture;
    this.display.uniforms.uFrame.value = [w, h];
    this.quad.material = this.display;
    r.setRenderTarget(null);
    r.render(this.quadScene, this.quadCamera);
    r.autoClear = autoClear;
  }

  /**
   * The neural layer of one asset drawn by the wasm CPU renderer for a perspective camera
   * (in the asset's glTF frame: the camera is taken relative to the asset's root object).
   * Resolves to `height * width * 4` floats, rows top first.
   */
  renderCPU(camera, width, height, asset = this.assets[0]) {
    if (!camera.isPerspectiveCamera && !camera.projectionMatrix) throw new Error('a camera is needed');
    camera.updateMatrixWorld();
    asset.root.updateMatrixWorld();
    const rel = new Matrix4().copy(asset.root.matrixWorld).invert().multiply(camera.matrixWorld);
    const k = pinholeOf(camera, width, height);
    return this.decoder.request({
      op: 'render', asset: asset.cpuAsset, ...k, camToWorld: Float32Array.from(rel.elements), width, height,
    }).then((r) => r.rgba);
  }

  _renderCPUFrame(camera, w, h) {
    if (camera.isOrthographicCamera) {
      if (!this._orthoWarned) console.info('dnr: the CPU renderer draws perspective cameras only; the fallback stays');
      this._orthoWarned = true;
      return;
    }
    for (const a of this.assets) {
      if (!a.cpuPending) {
        a.cpuPending = this.renderCPU(camera, w, h, a).then((rgba) => {
          a.cpuFrame = { rgba, w, h };
          a.cpuPending = null;
        }, (e) => { a.cpuPending = null; console.warn(`dnr: CPU frame failed: ${e.message}`); });
      }
      const f = a.cpuFrame;
      if (f) {
        if (!a.cpuTexture || a.cpuTexture.image.width !== f.w || a.cpuTexture.image.height !== f.h) {
          a.cpuTexture?.dispose();
          a.cpuTexture = new DataTexture(f.rgba, f.w, f.h, RGBAFormat, FloatType);
          a.cpuTexture.minFilter = NearestFilter;
          a.cpuTexture.magFilter = NearestFilter;
        } else {
          a.cpuTexture.image.data = f.rgba;
        }
        a.cpuTexture.needsUpdate = true;
        this._draw(a.cpuTexture, f.w, f.h);
      }
    }
  }

  /** Per-pixel cost of the U-Nets at a frame size (texture fetches, multiply-adds). */
  cost(width, height) {
    const out = [];
    for (const a of this.assets) for (const n of a.gpu?.nets || []) {
      if (n.cost) out.push({ renderer: n.global, passes: n.passCount, ...n.cost(width, height) });
    }
    return out;
  }
}
