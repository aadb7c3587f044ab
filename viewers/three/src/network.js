// GPU resources and passes of one decoded asset: neural textures as RGBA32F texture arrays,
// weights as RGBA32F textures (uploaded once), one program per network layer (compiled once),
// and frame-size-dependent render targets (allocated once per frame size).

import {
  DataArrayTexture, DataTexture, FloatType, NearestFilter, RGBAFormat, RawShaderMaterial,
  WebGLRenderTarget, GLSL3,
} from 'three';
import {
  WEIGHT_ROW, FULLSCREEN_VERTEX, featureAtlasShader, pixelNetShader, convShader,
  statsRowsShader, statsColsShader,
} from './glsl.js';

const groupsOf = (c) => Math.ceil(c / 4);

/** A renderer's `supersample` (spec revision 1.3; absent: 1). */
export function supersampleOf(r) {
  const s = r.supersample ?? 1;
  return Number.isInteger(s) && s >= 1 ? s : 1;
}

/** Uniforms of a supersampled feature shader (glsl.js featureMeanFunction). */
function supersampleUniforms() {
  return { uS0: { value: null }, uS1: { value: null }, uS: { value: 1 }, uSScale: { value: 1 } };
}

/**
 * Binds the subsample G-buffer `fine` = `{ target, s }` (s = 1: the frame's own G-buffer,
 * when the large one does not fit the GPU).
 */
function bindSubsamples(m, fine) {
  m.uniforms.uS0.value = fine.target.textures[0];
  m.uniforms.uS1.value = fine.target.textures[1];
  m.uniforms.uS.value = fine.s;
  m.uniforms.uSScale.value = Math.fround(1 / (fine.s * fine.s));
}

/** A float render target without depth, nearest sampling. */
export function floatTarget(width, height) {
  const rt = new WebGLRenderTarget(width, height, {
    type: FloatType, format: RGBAFormat, minFilter: NearestFilter, magFilter: NearestFilter,
    depthBuffer: false, stencilBuffer: false, generateMipmaps: false,
  });
  return rt;
}

export function passMaterial(fragmentShader, uniforms = {}) {
  return new RawShaderMaterial({
    glslVersion: GLSL3, vertexShader: FULLSCREEN_VERTEX, fragmentShader, uniforms,
    depthTest: false, depthWrite: false,
  });
}

function dataTexture(data, width, height) {
  const t = new DataTexture(data, width, height, RGBAFormat, FloatType);
  t.minFilter = NearestFilter;
  t.magFilter = NearestFilter;
  t.generateMipmaps = false;
  t.needsUpdate = true;
  return t;
}

/** Texels (vec4 each) packed into a 2D RGBA32F texture of WEIGHT_ROW texels per row. */
function weightTexture(texels) {
  const n = Math.max(1, texels.length / 4);
  const height = Math.ceil(n / WEIGHT_ROW);
  const width = height > 1 ? WEIGHT_ROW : n;
  const data = new Float32Array(width * height * 4);
  data.set(texels);
  return dataTexture(data, width, height);
}

/** Atlas geometry of a `channels x h x w` map, tiles as wide as the texture size allows. */
export function atlasGeometry(channels, w, h, maxSize) {
  const groups = groupsOf(channels);
  const cols = Math.max(1, Math.min(groups, Math.floor(maxSize / w)));
  const rows = Math.ceil(groups / cols);
  if (w > maxSize || rows * h > maxSize) {
    throw new Error(`a ${channels}-channel ${w}x${h} map does not fit a ${maxSize} texture`);
  }
  return { channels, groups, w, h, cols, rows, width: cols * w, height: rows * h };
}

/** A neural texture as one RGBA32F array texture: a layer per channel group, levels stacked. */
function neuralTexture(desc, levels, maxSize, maxLayers) {
  const C = desc.channels;
  const groups = groupsOf(C);
  const width = Math.max(...desc.levels.map((l) => l.width));
  const levelOffsets = [];
  let height = 0;
  for (const l of desc.levels) { levelOffsets.push(height); height += l.height; }
  if (width > maxSize || height > maxSize || groups > maxLayers) {
    throw new Error(`a neural texture of ${width}x${height} texels in ${groups} layers exceeds the GPU's limits`);
  }
  const data = new Float32Array(width * height * groups * 4);
  desc.levels.forEach((l, li) => {
    const src = levels[li];
    for (let j = 0; j < l.height; j++) {
      for (let i = 0; i < l.width; i++) {
        const s = (j * l.width + i) * C;
        for (let c = 0; c < C; c++) {
          const g = c >> 2;
          data[((g * height + levelOffsets[li] + j) * width + i) * 4 + (c & 3)] = src[s + c];
        }
      }
    }
  });
  const t = new DataArrayTexture(data, width, height, groups);
  t.format = RGBAFormat;
  t.type = FloatType;
  t.minFilter = NearestFilter;
  t.magFilter = NearestFilter;
  t.generateMipmaps = false;
  t.needsUpdate = true;
  return { texture: t, levelOffsets };
}

/**
 * The GPU form of one asset. `texBase`/`rendBase`: global indices of its first texture and
 * renderer (the G-buffer stores global indices, so several assets share a frame).
 */
export class AssetGPU {
  constructor(decoded, { texBase, rendBase, maxSize, maxLayers }) {
    const { desc, levels, tensors } = decoded;
    this.desc = desc;
    this.texBase = texBase;
    this.rendBase = rendBase;
    this.maxSize = maxSize;
    this.textures = desc.textures.map((t, i) => neuralTexture(t, levels[i], maxSize, maxLayers));
    this.nets = desc.renderers.map((r, ri) => {
      const used = [...new Set(desc.bindings.filter((b) => b.renderer === ri).map((b) => b.neuralTexture))];
      const texList = used.map((t) => ({
        index: texBase + t, desc: desc.textures[t], levelOffsets: this.textures[t].levelOffsets,
      }));
      const texUniforms = {};
      for (const t of used) texUniforms[`uT${texBase + t}`] = { value: this.textures[t].texture };
      const global = rendBase + ri;
      const net = r.architecture === 'unet'
        ? new UNetGPU(r, tensors[ri], global, texList, texUniforms, maxSize)
        : new PixelNetGPU(r, tensors[ri], global, texList, texUniforms);
      net.supersample = supersampleOf(r);
      return net;
    });
  }

  dispose() {
    for (const t of this.textures) t.texture.dispose();
    for (const n of this.nets) n.dispose();
  }
}

/** `none` and `mlp`: one pass per frame. */
class PixelNetGPU {
  constructor(r, tensors, global, texList, texUniforms) {
    this.arch = r.architecture;
    this.outChannels = r.outputChannels;
    this.global = global;
    const dims = [r.inputChannels, ...(r.hidden || []), r.outputChannels];
    const supersampled = supersampleOf(r) > 1;
    const uniforms = {
      ...texUniforms, uG0: { value: null }, uG1: { value: null }, uFrame: { value: [0, 0] },
      ...(supersampled ? supersampleUniforms() : {}),
    };
    let layout = null;
    if (this.arch === 'mlp') {
      const texels = [];
      layout = { layers: [] };
      let base = 0;
      for (let l = 0; l + 1 < dims.length; l++) {
        const [ci, co] = [dims[l], dims[l + 1]];
        const w = tensors[`layers.${l}.weight`];
        const b = tensors[`layers.${l}.bias`];
        const t = packConvTexels(co, [ci], 1, (o, c) => w[o * ci + c], b);
        layout.layers.push({ weightBase: base, biasBase: base + groupsOf(co) * groupsOf(ci) * 4 });
        for (const v of t) texels.push(v);
        base += t.length / 4;
      }
      this.weights = weightTexture(new Float32Array(texels));
      uniforms.uW = { value: this.weights };
    }
    this.material = passMaterial(pixelNetShader(global, texList, this.arch, dims, layout, supersampled), uniforms);
    this.passCount = 1;
  }

  /** Frame-size-dependent resources. */
  resize(width, height) {
    this.out?.dispose();
    this.out = floatTarget(width, height);
    this.frame = [width, height];
  }

  /**
   * Appends the frame's passes. `fine`: the subsample G-buffer `{ target, s }` of a
   * supersampled renderer.
   */
  passes(list, gbuf, fine) {
    const m = this.material;
    list.push({
      name: `r${this.global} ${this.arch}${fine ? ` (${fine.s}x${fine.s} subsamples)` : ''}`, material: m, target: this.out,
      set: () => {
        m.uniforms.uG0.value = gbuf.textures[0];
        m.uniforms.uG1.value = gbuf.textures[1];
        m.uniforms.uFrame.value = this.frame;
        if (fine) bindSubsamples(m, fine);
      },
    });
  }

  get output() { return this.out.texture; }

  get backgroundAlpha() { return false; }

  dispose() {
    this.material.dispose();
    this.weights?.dispose();
    this.out?.dispose();
  }
}

/**
 * Convolution weights in the texel order of glsl.js: for output group og, input group ig
 * (over the concatenated parts), tap t, lane j: the four weights get(4 og + o, c, t), o < 4,
 * of input channel c = 4 ig + j of its part; then one bias texel per output group.
 */
function packConvTexels(cOut, parts, taps, get, bias) {
  const og = groupsOf(cOut);
  const igs = parts.map(groupsOf);
  const igTotal = igs.reduce((a, b) => a + b, 0);
  const texels = new Float32Array((og * igTotal * taps * 4 + og) * 4);
  for (let g = 0; g < og; g++) {
    let igBase = 0;
    let cBase = 0;
    parts.forEach((cPart, k) => {
      for (let ig = 0; ig < igs[k]; ig++) {
        for (let t = 0; t < taps; t++) {
          for (let j = 0; j < 4; j++) {
            const c = 4 * ig + j;
            if (c >= cPart) continue;
            const texel = ((g * igTotal + igBase + ig) * taps + t) * 4 + j;
            for (let o = 0; o < 4; o++) {
              const oc = 4 * g + o;
              if (oc < cOut) texels[texel * 4 + o] = get(oc, cBase + c, t);
            }
          }
        }
      }
      igBase += igs[k];
      cBase += cPart;
    });
  }
  const biasBase = og * igTotal * taps * 4;
  for (let o = 0; o < cOut; o++) texels[(biasBase + (o >> 2)) * 4 + (o & 3)] = bias[o];
  return texels;
}

/**
 * `unet`: per frame, the feature atlas, D encoder and D decoder convolutions and, with
 * instance norm, 4 statistics passes per normalised map (2 D - 1 of them): a pass count
 * fixed by the architecture (1 + 2 D + 4 (2 D - 1) with instance norm, 1 + 2 D without).
 */
class UNetGPU {
  constructor(r, tensors, global, texList, texUniforms, maxSize) {
    this.global = global;
    this.maxSize = maxSize;
    this.C = r.inputChannels;
    this.outChannels = r.outputChannels;
    this.widths = r.widths;
    this.D = r.widths.length;
    this.decoder = r.decoder;
    this.norm = r.normalization === 'instance';
    const D = this.D;
    const w = this.widths;
    const supersampled = supersampleOf(r) > 1;
    this.featureMat = passMaterial(featureAtlasShader(global, texList, this.C, supersampled), {
      ...texUniforms, uG0: { value: null }, uG1: { value: null }, uFrame: { value: [0, 0] },
      uOut: { value: [0, 0, 0] }, ...(supersampled ? supersampleUniforms() : {}),
    });
    // Encoders.
    this.enc = [];
    for (let i = 0; i < D; i++) {
      const cin = i === 0 ? this.C : w[i - 1];
      const wt = tensors[`encoder.${i}.weight`];
      const texels = packConvTexels(w[i], [cin], 16, (o, c, t) => wt[(o * cin + c) * 16 + t], tensors[`encoder.${i}.bias`]);
      const weights = weightTexture(texels);
      const parts = [{ groups: groupsOf(cin), norm: i > 0 && this.norm, act: i > 0 }];
      const biasBase = groupsOf(w[i]) * groupsOf(cin) * 16 * 4;
      this.enc.push({ weights, parts, material: this._convMaterial('enc', parts, groupsOf(w[i]), biasBase, weights, false) });
    }
    // Decoders, i = D-1 .. 0 stored at index i.
    this.dec = [];
    const tconv = this.decoder === 'transposedConv';
    const taps = tconv ? 16 : 9;
    for (let i = D - 1; i >= 0; i--) {
      const cinParts = i === D - 1 ? [w[D - 1]] : [w[i], w[i]];
      const cin = cinParts.reduce((a, b) => a + b, 0);
      const cout = i === 0 ? this.outChannels : w[i - 1];
      const wt = tensors[`decoder.${i}.weight`];
      const get = tconv
        ? (o, c, t) => wt[(c * cout + o) * 16 + t]
        : (o, c, t) => wt[(o * cin + c) * 9 + t];
      const texels = packConvTexels(cout, cinParts, taps, get, tensors[`decoder.${i}.bias`]);
      const weights = weightTexture(texels);
      const parts = cinParts.map((c) => ({ groups: groupsOf(c), norm: this.norm, act: true }));
      const igTotal = parts.reduce((a, p) => a + p.groups, 0);
      const biasBase = groupsOf(cout) * igTotal * taps * 4;
      this.dec[i] = {
        weights, parts,
        material: this._convMaterial(tconv ? 'tconv' : 'upconv', parts, groupsOf(cout), biasBase, weights, i === 0),
      };
    }
    if (this.norm) {
      const u = () => ({ uA: { value: null }, uAGeo: { value: [0, 0, 0] }, uM: { value: null } });
      this.statMats = [
        passMaterial(statsRowsShader(false), u()), passMaterial(statsColsShader(false), { uRows: { value: null }, uAGeo: { value: [0, 0, 0] } }),
        passMaterial(statsRowsShader(true), u()), passMaterial(statsColsShader(true), { uRows: { value: null }, uAGeo: { value: [0, 0, 0] } }),
      ];
    }
    this.passCount = 1 + 2 * D + (this.norm ? 4 * (2 * D - 1) : 0);
  }

  _convMaterial(kind, parts, outGroups, biasBase, weights, final) {
    const uniforms = { uW: { value: weights }, uOut: { value: [0, 0, 0] } };
    parts.forEach((p, k) => {
      uniforms[`uA${k}`] = { value: null };
      uniforms[`uA${k}Geo`] = { value: [0, 0, 0] };
      if (p.norm) { uniforms[`uM${k}`] = { value: null }; uniforms[`uR${k}`] = { value: null }; }
    });
    return passMaterial(convShader({ kind, parts, outGroups, biasBase, final, outChannels: this.outChannels }), uniforms);
  }

  resize(width, height) {
    this._disposeFrame();
    const P = 2 ** this.D;
    const Wp = Math.ceil(width / P) * P;
    const Hp = Math.ceil(height / P) * P;
    this.frame = [width, height];
    const map = (channels, w, h, stats) => {
      const geo = atlasGeometry(channels, w, h, this.maxSize);
      const m = { geo, rt: floatTarget(geo.width, geo.height) };
      if (stats && this.norm) {
        m.rows = floatTarget(geo.cols, geo.rows * h);
        m.mean = floatTarget(geo.groups, 1);
        m.rstd = floatTarget(geo.groups, 1);
      }
      return m;
    };
    this.x = map(this.C, Wp, Hp, false);
    this.e = this.widths.map((c, i) => map(c, Wp >> (i + 1), Hp >> (i + 1), true));
    this.y = [];
    for (let i = this.D - 1; i >= 1; i--) this.y[i] = map(this.widths[i - 1], Wp >> i, Hp >> i, true);
    this.out = floatTarget(width, height);
  }

  _disposeFrame() {
    const all = [this.x, ...(this.e || []), ...(this.y || []).filter(Boolean)];
    for (const m of all) {
      if (!m) continue;
      m.rt.dispose(); m.rows?.dispose(); m.mean?.dispose(); m.rstd?.dispose();
    }
    this.out?.dispose();
  }

  static geoOf(m) { return [m.geo.w, m.geo.h, m.geo.cols]; }

  _statsPasses(list, m, name) {
    if (!this.norm) return;
    const [rowsMean, colsMean, rowsVar, colsVar] = this.statMats;
    const geo = UNetGPU.geoOf(m);
    list.push({ name: `${name} mean rows`, material: rowsMean, target: m.rows, set: () => { rowsMean.uniforms.uA.value = m.rt.texture; rowsMean.uniforms.uAGeo.value = geo; } });
    list.push({ name: `${name} mean`, material: colsMean, target: m.mean, set: () => { colsMean.uniforms.uRows.value = m.rows.texture; colsMean.uniforms.uAGeo.value = geo; } });
    list.push({ name: `${name} var rows`, material: rowsVar, target: m.rows, set: () => { rowsVar.uniforms.uA.value = m.rt.texture; rowsVar.uniforms.uAGeo.value = geo; rowsVar.uniforms.uM.value = m.mean.texture; } });
    list.push({ name: `${name} rstd`, material: colsVar, target: m.rstd, set: () => { colsVar.uniforms.uRows.value = m.rows.texture; colsVar.uniforms.uAGeo.value = geo; } });
  }

  _bindParts(mat, inputs) {
    inputs.forEach((m, k) => {
      mat.uniforms[`uA${k}`].value = m.rt.texture;
      mat.uniforms[`uA${k}Geo`].value = UNetGPU.geoOf(m);
      if (mat.uniforms[`uM${k}`]) {
        mat.uniforms[`uM${k}`].value = m.mean.texture;
        mat.uniforms[`uR${k}`].value = m.rstd.texture;
      }
    });
  }

  passes(list, gbuf, fine) {
    const f = this.featureMat;
    list.push({
      name: `r${this.global} features${fine ? ` (${fine.s}x${fine.s} subsamples)` : ''}`, material: f, target: this.x.rt,
      set: () => {
        f.uniforms.uG0.value = gbuf.textures[0];
        f.uniforms.uG1.value = gbuf.textures[1];
        f.uniforms.uFrame.value = this.frame;
        f.uniforms.uOut.value = UNetGPU.geoOf(this.x);
        if (fine) bindSubsamples(f, fine);
      },
    });
    for (let i = 0; i < this.D; i++) {
      const mat = this.enc[i].material;
      const src = i === 0 ? this.x : this.e[i - 1];
      const dst = this.e[i];
      list.push({
        name: `r${this.global} encoder.${i}`, material: mat, target: dst.rt,
        set: () => { this._bindParts(mat, [src]); mat.uniforms.uOut.value = UNetGPU.geoOf(dst); },
      });
      this._statsPasses(list, dst, `r${this.global} encoder.${i}`);
    }
    for (let i = this.D - 1; i >= 0; i--) {
      const mat = this.dec[i].material;
      const inputs = i === this.D - 1 ? [this.e[this.D - 1]] : [this.y[i + 1], this.e[i]];
      const dst = i === 0 ? null : this.y[i];
      list.push({
        name: `r${this.global} decoder.${i}`, material: mat, target: dst ? dst.rt : this.out,
        set: () => {
          this._bindParts(mat, inputs);
          mat.uniforms.uOut.value = dst ? UNetGPU.geoOf(dst) : [this.frame[0], this.frame[1], 1];
        },
      });
      if (dst) this._statsPasses(list, dst, `r${this.global} decoder.${i}`);
    }
  }

  get output() { return this.out.texture; }

  get backgroundAlpha() { return this.outChannels === 4; }

  /** Per output pixel of a `width x height` frame: texture fetches and multiply-adds. */
  cost(width, height) {
    const P = 2 ** this.D;
    const Wp = Math.ceil(width / P) * P;
    const Hp = Math.ceil(height / P) * P;
    let fetches = 0;
    let macs = 0;
    let bytes = 0;
    const w = this.widths;
    const tconv = this.decoder === 'transposedConv';
    for (let i = 0; i < this.D; i++) {
      const cin = i === 0 ? this.C : w[i - 1];
      const n = (Wp >> (i + 1)) * (Hp >> (i + 1)) * groupsOf(w[i]);
      fetches += n * groupsOf(cin) * 16 * 5; // per input group and tap: 1 input + 4 weight texels
      macs += n * 4 * cin * 16;
      bytes += n * 16;
    }
    for (let i = this.D - 1; i >= 0; i--) {
      const cin = i === this.D - 1 ? w[this.D - 1] : 2 * w[i];
      const cout = i === 0 ? this.outChannels : w[i - 1];
      const n = i === 0 ? width * height : (Wp >> i) * (Hp >> i) * groupsOf(cout);
      const taps = tconv ? 4 : 9;
      fetches += n * groupsOf(cin) * taps * 5;
      macs += n * 4 * cin * taps;
      bytes += n * 16;
    }
    return { fetches, macs, bytes };
  }

  dispose() {
    this._disposeFrame();
    this.featureMat.dispose();
    for (const l of [...this.enc, ...this.dec]) { l.material.dispose(); l.weights.dispose(); }
    for (const m of this.statMats || []) m.dispose();
  }
}

export { packConvTexels };
