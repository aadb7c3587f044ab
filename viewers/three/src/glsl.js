// GLSL ES 3.00 sources of the neural passes. Every pass is a full-frame triangle into an
// RGBA32F target and reads its inputs with texelFetch in f32 (no hardware filtering).
//
// Tensors (feature images, activations) are *atlases*: channel group g (channels 4g..4g+3) of
// a `w x h` map is the tile at column g % cols, row floor(g / cols); texel row y is image row y
// (row 0 at the top). Weights are RGBA32F texels in a 2D texture of WEIGHT_ROW texels per row;
// texel ((og * IG + ig) * T + t) * 4 + j holds the weights from input channel 4 ig + j at tap
// t to output channels 4 og .. 4 og + 3, so a fragment that computes one output group fetches
// each of its weights exactly once.

export const WEIGHT_ROW = 4096;

export const HEADER = `precision highp float;
precision highp int;
precision highp sampler2D;
precision highp sampler2DArray;
`;

export const FULLSCREEN_VERTEX = `${HEADER}
in vec3 position;
void main() { gl_Position = vec4(position.xy, 0.0, 1.0); }
`;

const WEIGHT_FETCH = `
uniform sampler2D uW;
vec4 fw(int i) { return texelFetch(uW, ivec2(i % ${WEIGHT_ROW}, i / ${WEIGHT_ROW}), 0); }
mat4 fw4(int i) { return mat4(fw(i), fw(i + 1), fw(i + 2), fw(i + 3)); }
`;

// Atlas addressing of the output fragment: og, x, y from gl_FragCoord and uOut = (w, h, cols).
const OUT_TILE = `
uniform ivec3 uOut;
void outTile(out int og, out int x, out int y) {
  ivec2 p = ivec2(gl_FragCoord.xy);
  ivec2 tile = p / uOut.xy;
  og = tile.y * uOut.z + tile.x;
  x = p.x - tile.x * uOut.x;
  y = p.y - tile.y * uOut.y;
}
`;

/** LeakyReLU(0.2) of four values, exactly `v < 0 ? 0.2 v : v`. */
const LRELU = `vec4 lrelu(vec4 v) { return max(v, 0.2 * v); }`;

/**
 * tanh without overflow (GLSL's may be (e^x - e^-x) / (e^x + e^-x), NaN beyond |x| ~ 44).
 * Absolute error about 1e-7 near 0, far below an 8-bit step.
 */
const TANH = `vec4 tanhS(vec4 x) {
  vec4 e = exp(2.0 * min(abs(x), vec4(15.0)));
  return sign(x) * (1.0 - 2.0 / (e + 1.0));
}`;

/**
 * Sum of `n` vec4 terms `TERM(i)`, i = 0 .. n-1, by pairwise (binary-counter) summation of
 * blocks of 8: the error grows with log n, not n (spec, Implementation Notes, precision).
 */
function pairwiseSum(result, n, term) {
  return `
  vec4 ${result};
  {
    vec4 st[24];
    int cnt = 0;
    for (int b0 = 0; b0 < ${n}; b0 += 8) {
      vec4 b = vec4(0.0);
      for (int k = 0; k < 8; k++) {
        int i = b0 + k;
        if (i < ${n}) { b += ${term}; }
      }
      int c = cnt;
      int lv = 0;
      while ((c & 1) == 1) { b += st[lv]; c >>= 1; lv++; }
      st[lv] = b;
      cnt++;
    }
    ${result} = vec4(0.0);
    for (int lv = 0; lv < 24; lv++) {
      if (((cnt >> lv) & 1) == 1) { ${result} += st[lv]; }
    }
  }`;
}

/** Real SH basis Y_j(d), j < 16 (spec table, f32 constants). */
const SH = `
float shY(int j, vec3 d) {
  float x = d.x, y = d.y, z = d.z;
  if (j == 0) return 0.28209479177387814;
  if (j == 1) return -0.4886025119029199 * y;
  if (j == 2) return 0.4886025119029199 * z;
  if (j == 3) return -0.4886025119029199 * x;
  if (j == 4) return 1.0925484305920792 * x * y;
  if (j == 5) return -1.0925484305920792 * y * z;
  if (j == 6) return 0.31539156525252005 * (2.0 * z * z - x * x - y * y);
  if (j == 7) return -1.0925484305920792 * x * z;
  if (j == 8) return 0.5462742152960396 * (x * x - y * y);
  if (j == 9) return -0.5900435899266435 * y * (3.0 * x * x - y * y);
  if (j == 10) return 2.890611442640554 * x * y * z;
  if (j == 11) return -0.4570457994644658 * y * (4.0 * z * z - x * x - y * y);
  if (j == 12) return 0.3731763325901154 * z * (2.0 * z * z - 3.0 * x * x - 3.0 * y * y);
  if (j == 13) return -0.4570457994644658 * x * (4.0 * z * z - x * x - y * y);
  if (j == 14) return 1.445305721320277 * z * (x * x - y * y);
  if (j == 15) return -0.5900435899266435 * x * (x * x - 3.0 * y * y);
  return 0.0;
}
`;

/** Wrap of an integer tap index against n (0 REPEAT, 1 CLAMP_TO_EDGE, 2 MIRRORED_REPEAT). */
const WRAP = `
int wrapRep(int i, int n) { return i >= 0 ? i % n : n - 1 - ((-i - 1) % n); }
int wrapIdx(int i, int n, int mode) {
  if (mode == 0) return wrapRep(i, n);
  if (mode == 1) return clamp(i, 0, n - 1);
  int m = wrapRep(i, 2 * n);
  return m < n ? m : 2 * n - 1 - m;
}
`;

const WRAP_CODE = { 10497: 0, 33071: 1, 33648: 2 };

/**
 * The feature-sampling functions of one renderer: `vec4 feature(int g, vec4 gb0, vec3 d)`
 * gives channels 4g..4g+3 of X at a covered pixel whose G-buffer holds uv = gb0.xy and
 * neural texture gb0.z (-1: no uv, F = 0), with local view direction d. `textures` lists
 * `{ index, desc, levelOffsets }` of the textures the renderer's primitives use; texture t
 * is the sampler2DArray uT<t> (one layer per channel group, levels stacked vertically).
 */
export function featureFunctions(textures, channels) {
  let src = `${WRAP}${SH}`;
  for (const { index, desc, levelOffsets } of textures) {
    src += `uniform sampler2DArray uT${index};\n`;
    src += `vec4 sampleT${index}(int g, vec2 uv) {\n  vec4 s = vec4(0.0);\n`;
    desc.levels.forEach((l, li) => {
      const ws = WRAP_CODE[desc.wrapS];
      const wt = WRAP_CODE[desc.wrapT];
      src += `  {
    float x = uv.x * ${l.width}.0 - 0.5;
    float y = uv.y * ${l.height}.0 - 0.5;
    float x0 = floor(x), y0 = floor(y);
    float fx = x - x0, fy = y - y0;
    int ix = int(x0), iy = int(y0);
    int xa = wrapIdx(ix, ${l.width}, ${ws}), xb = wrapIdx(ix + 1, ${l.width}, ${ws});
    int ya = wrapIdx(iy, ${l.height}, ${wt}) + ${levelOffsets[li]}, yb = wrapIdx(iy + 1, ${l.height}, ${wt}) + ${levelOffsets[li]};
    s += (1.0 - fx) * (1.0 - fy) * texelFetch(uT${index}, ivec3(xa, ya, g), 0);
    s += fx * (1.0 - fy) * texelFetch(uT${index}, ivec3(xb, ya, g), 0);
    s += (1.0 - fx) * fy * texelFetch(uT${index}, ivec3(xa, yb, g), 0);
    s += fx * fy * texelFetch(uT${index}, ivec3(xb, yb, g), 0);
  }\n`;
    });
    src += `  return s;\n}\n`;
    const vd = desc.viewDependence;
    src += `vec4 modulateT${index}(int g, vec4 f, vec3 d) {\n`;
    if (vd) {
      const n = (vd.degree + 1) * (vd.degree + 1);
      src += `  for (int k = 0; k < 4; k++) {
    int j = 4 * g + k - ${vd.firstChannel};
    if (j >= 0 && j < ${n}) f[k] *= shY(j, d);
  }\n`;
    }
    src += `  return f;\n}\n`;
  }
  src += `vec4 feature(int g, vec4 gb0, vec3 d) {
  int t = int(round(gb0.z));
  vec2 uv = gb0.xy;
  if (t < 0 || any(isnan(uv)) || any(isinf(uv))) return vec4(0.0);
  if (any(isnan(d)) || any(isinf(d))) d = vec3(0.0);\n`;
  for (const { index } of textures) {
    src += `  if (t == ${index}) return modulateT${index}(g, sampleT${index}(g, uv), d);\n`;
  }
  src += `  return vec4(0.0);\n}\n`;
  void channels;
  return src;
}

/** Reads the G-buffer of image pixel (x, y) (row 0 at the top; the G-buffer is bottom-up). */
const GBUF = `
uniform sampler2D uG0;
uniform sampler2D uG1;
uniform ivec2 uFrame;
vec4 gb0At(int x, int y) { return texelFetch(uG0, ivec2(x, uFrame.y - 1 - y), 0); }
vec3 gb1At(int x, int y) { return texelFetch(uG1, ivec2(x, uFrame.y - 1 - y), 0).xyz; }
`;

/**
 * Supersampled features (spec, Supersampled Features): `featureMean(g, x, y)` is the mean of
 * channels 4g..4g+3 of X over the uS x uS subsamples of image pixel (x, y), read from the
 * G-buffer drawn at uS times the frame (uS0, uS1; bottom-up). A subsample whose primitive is
 * not the renderer's adds 0. Summed row by row and scaled by uSScale = f32(1 / uS^2), as the
 * dnr runtime's box mean does. With uS = 1 and the frame's own G-buffer (the fallback when
 * the large one does not fit the GPU), it is the pixel-centre feature of owned pixels.
 */
function featureMeanFunction(rendererIndex) {
  return `
uniform sampler2D uS0;
uniform sampler2D uS1;
uniform int uS;
uniform float uSScale;
vec4 featureMean(int g, int x, int y) {
  vec4 acc = vec4(0.0);
  int top = uS * (uFrame.y - y) - 1;
  for (int j = 0; j < uS; j++) {
    for (int i = 0; i < uS; i++) {
      ivec2 t = ivec2(uS * x + i, top - j);
      vec4 gb0 = texelFetch(uS0, t, 0);
      if (int(round(gb0.w)) == ${rendererIndex + 1}) acc += feature(g, gb0, texelFetch(uS1, t, 0).xyz);
    }
  }
  return acc * uSScale;
}
`;
}

/**
 * Feature atlas of a U-Net renderer (padded frame; zero outside the frame and uncovered).
 * `supersampled`: every frame pixel gets its subsample mean instead, whatever owns its centre.
 */
export function featureAtlasShader(rendererIndex, textures, channels, supersampled = false) {
  const body = supersampled
    ? '  o = featureMean(g, x, y);'
    : `  vec4 gb0 = gb0At(x, y);
  if (int(round(gb0.w)) != ${rendererIndex + 1}) return;
  o = feature(g, gb0, gb1At(x, y));`;
  return `${HEADER}${GBUF}${OUT_TILE}${featureFunctions(textures, channels)}${supersampled ? featureMeanFunction(rendererIndex) : ''}
out vec4 o;
void main() {
  int g, x, y;
  outTile(g, x, y);
  o = vec4(0.0);
  if (g >= ${Math.ceil(channels / 4)} || x >= uFrame.x || y >= uFrame.y) return;
${body}
}
`;
}

/**
 * `none` and `mlp` in one pass over the frame: features, dense layers (weights in uW, the
 * layout of `denseLayout`), output transform. Uncovered pixels get 0 (the composite ignores
 * them). `dims` are the layer sizes [C, h1, ..., out]. `supersampled`: covered pixels take
 * their subsample mean as features (coverage stays the pixel centre's).
 */
export function pixelNetShader(rendererIndex, textures, arch, dims, layout, supersampled = false) {
  const groups = (c) => Math.ceil(c / 4);
  const C = dims[0];
  let body = `  vec4 a0[${groups(C)}];
  for (int g = 0; g < ${groups(C)}; g++) a0[g] = ${supersampled ? 'featureMean(g, x, y)' : 'feature(g, gb0, d)'};\n`;
  if (arch === 'none') {
    body += `  o = vec4(clamp(a0[0].xyz, 0.0, 1.0), 1.0);\n`;
  } else {
    const last = dims.length - 2;
    for (let l = 0; l <= last; l++) {
      const gi = groups(dims[l]);
      const go = groups(dims[l + 1]);
      const { weightBase, biasBase } = layout.layers[l];
      body += `  vec4 a${l + 1}[${go}];
  for (int og = 0; og < ${go}; og++) {
    vec4 acc = fw(${biasBase} + og);
    for (int ig = 0; ig < ${gi}; ig++) acc += fw4(${weightBase} + (og * ${gi} + ig) * 4) * a${l}[ig];
    a${l + 1}[og] = ${l === last ? 'tanhS(acc)' : 'lrelu(acc)'};
  }\n`;
    }
    const out = dims[dims.length - 1];
    body += `  vec4 t = a${last + 1}[0];
  o = vec4(0.5 * (t.xyz + 1.0), ${out === 4 ? '0.5 * (t.w + 1.0)' : '1.0'});\n`;
  }
  return `${HEADER}${GBUF}${WEIGHT_FETCH}${LRELU}\n${TANH}\n${featureFunctions(textures, dims[0])}${supersampled ? featureMeanFunction(rendererIndex) : ''}
out vec4 o;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int x = p.x, y = p.y;
  o = vec4(0.0);
  vec4 gb0 = gb0At(x, y);
  if (int(round(gb0.w)) != ${rendererIndex + 1}) return;
  vec3 d = gb1At(x, y);
${body}}
`;
}

/**
 * One U-Net convolution. `kind`: 'enc' (Conv4x4 s2 p1), 'tconv' (ConvT4x4 s2 p1, gather form),
 * 'upconv' (Nearest2x then Conv3x3 s1 p1). `parts`: the concatenated inputs, each
 * `{ groups, norm, act }` read from uA<k> (atlas, uA<k>Geo = (w, h, cols)) and, with norm,
 * its mean uM<k> and 1/std uR<k> (one texel per group). `final`: the output layer (tanh and
 * the output transform, frame-sized, `outChannels` 3 or 4).
 */
export function convShader({ kind, parts, outGroups, biasBase, final, outChannels }) {
  const taps = kind === 'upconv' ? 9 : 16;
  const igTotal = parts.reduce((s, p) => s + p.groups, 0);
  let decl = '';
  let loops = '';
  let igOffset = 0;
  parts.forEach((p, k) => {
    decl += `uniform sampler2D uA${k};\nuniform ivec3 uA${k}Geo;\n`;
    if (p.norm) decl += `uniform sampler2D uM${k};\nuniform sampler2D uR${k};\n`;
    decl += `vec4 readA${k}(int g, int x, int y) {
  ivec3 G = uA${k}Geo;
  return texelFetch(uA${k}, ivec2((g % G.z) * G.x + x, (g / G.z) * G.y + y), 0);
}\n`;
    const norm = p.norm ? `(v - m) * r` : 'v';
    const value = p.act ? `lrelu(${norm})` : norm;
    let tap;
    if (kind === 'enc') {
      tap = `
    for (int ky = 0; ky < 4; ky++) {
      int iy = 2 * y + ky - 1;
      if (iy < 0 || iy >= uA${k}Geo.y) continue;
      for (int kx = 0; kx < 4; kx++) {
        int ix = 2 * x + kx - 1;
        if (ix < 0 || ix >= uA${k}Geo.x) continue;
        vec4 v = readA${k}(ig, ix, iy);
        acc += fw4(wb + (ky * 4 + kx) * 4) * ${value};
      }
    }`;
    } else if (kind === 'tconv') {
      tap = `
    for (int a = 0; a < 2; a++) {
      int ky = ky0 + 2 * a;
      int iy = hy - a;
      if (iy < 0 || iy >= uA${k}Geo.y) continue;
      for (int b = 0; b < 2; b++) {
        int kx = kx0 + 2 * b;
        int ix = hx - b;
        if (ix < 0 || ix >= uA${k}Geo.x) continue;
        vec4 v = readA${k}(ig, ix, iy);
        acc += fw4(wb + (ky * 4 + kx) * 4) * ${value};
      }
    }`;
    } else {
      tap = `
    for (int ky = 0; ky < 3; ky++) {
      int uy = y + ky - 1;
      if (uy < 0 || uy >= 2 * uA${k}Geo.y) continue;
      for (int kx = 0; kx < 3; kx++) {
        int ux = x + kx - 1;
        if (ux < 0 || ux >= 2 * uA${k}Geo.x) continue;
        vec4 v = readA${k}(ig, ux >> 1, uy >> 1);
        acc += fw4(wb + (ky * 3 + kx) * 4) * ${value};
      }
    }`;
    }
    loops += `
  for (int ig = 0; ig < ${p.groups}; ig++) {
    ${p.norm ? `vec4 m = texelFetch(uM${k}, ivec2(ig, 0), 0);\n    vec4 r = texelFetch(uR${k}, ivec2(ig, 0), 0);` : ''}
    int wb = ((og * ${igTotal} + ${igOffset} + ig) * ${taps}) * 4;${tap}
  }`;
    igOffset += p.groups;
  });
  const pre = kind === 'tconv'
    ? `  int ky0 = (y + 1) & 1, kx0 = (x + 1) & 1;
  int hy = (y + 1 - ky0) / 2, hx = (x + 1 - kx0) / 2;\n`
    : '';
  const head = final
    ? `  ivec2 p = ivec2(gl_FragCoord.xy);
  int og = 0, x = p.x, y = p.y;\n`
    : `  int og, x, y;
  outTile(og, x, y);
  if (og >= ${outGroups}) { o = vec4(0.0); return; }\n`;
  const tail = final
    ? `  vec4 t = tanhS(acc);
  o = vec4(0.5 * (t.xyz + 1.0), ${outChannels === 4 ? '0.5 * (t.w + 1.0)' : '1.0'});\n`
    : `  o = acc;\n`;
  return `${HEADER}${WEIGHT_FETCH}${OUT_TILE}${LRELU}\n${TANH}\n${decl}
out vec4 o;
void main() {
${head}${pre}  vec4 acc = fw(${biasBase} + og);${loops}
${tail}}
`;
}

/**
 * Instance-norm statistics, pass 1 of 2: per channel group and row, the sum over the row of
 * x (or of (x - mean)^2 with `variance`), pairwise. Output atlas of 1-texel-wide tiles.
 */
export function statsRowsShader(variance) {
  return `${HEADER}
uniform sampler2D uA;
uniform ivec3 uAGeo;
${variance ? 'uniform sampler2D uM;' : ''}
out vec4 o;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int tx = p.x, ty = p.y / uAGeo.y;
  int y = p.y - ty * uAGeo.y;
  int g = ty * uAGeo.z + tx;
  ivec2 base = ivec2(tx * uAGeo.x, ty * uAGeo.y + y);
  ${variance ? 'vec4 m = texelFetch(uM, ivec2(g, 0), 0);' : ''}
  ${pairwiseSum('s', 'uAGeo.x', variance
    ? '(texelFetch(uA, base + ivec2(i, 0), 0) - m) * (texelFetch(uA, base + ivec2(i, 0), 0) - m)'
    : 'texelFetch(uA, base + ivec2(i, 0), 0)')}
  o = s;
}
`;
}

/**
 * Pass 2 of 2: per group, the pairwise sum of the row sums, giving the mean (or, with
 * `variance`, 1 / sqrt(var + 1e-5)). Output: one texel per group.
 */
export function statsColsShader(variance) {
  return `${HEADER}
uniform sampler2D uRows;
uniform ivec3 uAGeo;
out vec4 o;
void main() {
  int g = int(gl_FragCoord.x);
  ivec2 base = ivec2(g % uAGeo.z, (g / uAGeo.z) * uAGeo.y);
  ${pairwiseSum('s', 'uAGeo.y', 'texelFetch(uRows, base + ivec2(0, i), 0)')}
  float n = float(uAGeo.x * uAGeo.y);
  o = ${variance ? '1.0 / sqrt(s / n + 1e-5)' : 's / n'};
}
`;
}

/**
 * Which renderers cover at least one pixel: pass 1 (`rows`) gives, per row and group of 4
 * renderers, 1 where the row holds a pixel of the renderer; pass 2 the maximum over rows.
 */
export function coverageShader(rows) {
  if (rows) {
    return `${HEADER}
uniform sampler2D uG0;
uniform ivec2 uFrame;
out vec4 o;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int g = p.x;
  vec4 f = vec4(0.0);
  for (int x = 0; x < uFrame.x; x++) {
    int rid = int(round(texelFetch(uG0, ivec2(x, p.y), 0).w)) - 1 - 4 * g;
    if (rid >= 0 && rid < 4) f[rid] = 1.0;
  }
  o = f;
}
`;
  }
  return `${HEADER}
uniform sampler2D uRows;
uniform ivec2 uFrame;
out vec4 o;
void main() {
  int g = int(gl_FragCoord.x);
  vec4 f = vec4(0.0);
  for (int y = 0; y < uFrame.y; y++) f = max(f, texelFetch(uRows, ivec2(g, y), 0));
  o = f;
}
`;
}

/**
 * The neural layer N (spec, Compositing Several Renderers), straight alpha, image rows top
 * first. `renderers[r] = { present, backgroundAlpha }`: present renderers have an output
 * texture uO<r>; backgroundAlpha ones (4-channel U-Nets) composite source-over at background
 * pixels, in ascending index, when they cover a pixel (flags uCov).
 */
export function compositeShader(renderers) {
  let decl = '';
  let owned = '';
  let bg = '';
  renderers.forEach((r, i) => {
    if (!r.present) return;
    decl += `uniform sampler2D uO${i};\n`;
    owned += `    if (rid == ${i + 1}) o = texelFetch(uO${i}, p, 0);\n`;
    if (r.backgroundAlpha) {
      bg += `    if (texelFetch(uCov, ivec2(${i >> 2}, 0), 0)[${i & 3}] > 0.0) {
      vec4 c = texelFetch(uO${i}, p, 0);
      Q = c.a * c.rgb + (1.0 - c.a) * Q;
      A = c.a + (1.0 - c.a) * A;
    }\n`;
    }
  });
  return `${HEADER}
uniform sampler2D uG0;
uniform sampler2D uCov;
uniform ivec2 uFrame;
${decl}
out vec4 o;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int rid = int(round(texelFetch(uG0, ivec2(p.x, uFrame.y - 1 - p.y), 0).w));
  o = vec4(0.0);
  if (rid > 0) {
${owned}  } else if (rid == 0) {
    vec3 Q = vec3(0.0);
    float A = 0.0;
${bg}    if (A > 0.0) o = vec4(Q / A, A);
  }
}
`;
}

/** Draws N (image rows top first) onto the bound framebuffer (bottom-up), for blending. */
export const DISPLAY_SHADER = `${HEADER}
uniform sampler2D uN;
uniform ivec2 uFrame;
out vec4 o;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  o = texelFetch(uN, ivec2(p.x, uFrame.y - 1 - p.y), 0);
}
`;

/** G-buffer vertex shader (three.js ShaderMaterial, GLSL3): local position, local eye, uv. */
export const GBUFFER_VERTEX = `
#include <common>
#include <batching_pars_vertex>
#include <morphtarget_pars_vertex>
#include <skinning_pars_vertex>
uniform bool uOrtho;
uniform vec3 uCamDir;
out vec3 vLocal;
flat out vec3 vEye;
out vec2 vUv;
#ifdef DNR_EXACT
in vec3 aP0, aP1, aP2;
in vec2 aT0, aT1, aT2;
uniform vec2 uViewport;
flat out vec3 vP0, vP1, vP2;
flat out vec2 vT0, vT1, vT2;
flat out vec2 vS0, vS1, vS2;
flat out float vExact;
float cross2(vec2 a, vec2 b) { return a.x * b.y - a.y * b.x; }
vec2 toScreen(vec4 c) { return (c.xy / c.w * 0.5 + 0.5) * uViewport; }
#endif
void main() {
  #ifdef DNR_EXACT
  vP0 = aP0; vP1 = aP1; vP2 = aP2; vT0 = aT0; vT1 = aT1; vT2 = aT2;
  #endif
  #include <batching_vertex>
  #include <skinbase_vertex>
  #include <morphinstance_vertex>
  #include <begin_vertex>
  #include <morphtarget_vertex>
  #include <skinning_vertex>
  #include <project_vertex>
  vLocal = transformed;
  #ifdef DNR_EXACT
  // Coverage decided at pixel centres from the exact triangle (fragment shader): the
  // triangle is grown here by 3/4 pixel in screen space (each vertex moved to where its two
  // edges, pushed outwards, meet), so every pixel centre inside it gets a fragment even when
  // the rasteriser snaps vertices coarsely.
  mat4 mvp = projectionMatrix * modelViewMatrix;
  vec4 c0 = mvp * vec4(aP0, 1.0), c1 = mvp * vec4(aP1, 1.0), c2 = mvp * vec4(aP2, 1.0);
  vExact = (c0.w > 0.0 && c1.w > 0.0 && c2.w > 0.0) ? 1.0 : 0.0;
  vS0 = vS1 = vS2 = vec2(0.0);
  if (vExact > 0.5) {
    vS0 = toScreen(c0); vS1 = toScreen(c1); vS2 = toScreen(c2);
    float sgn = cross2(vS1 - vS0, vS2 - vS0) >= 0.0 ? 1.0 : -1.0;
    vec2 a = vS2, v = vS0, b = vS1;
    if (position == aP1) { a = vS0; v = vS1; b = vS2; }
    else if (position == aP2) { a = vS1; v = vS2; b = vS0; }
    vec2 ea = v - a, eb = b - v;
    if (dot(ea, ea) > 0.0 && dot(eb, eb) > 0.0) {
      vec2 na = sgn * normalize(vec2(ea.y, -ea.x));
      vec2 nb = sgn * normalize(vec2(eb.y, -eb.x));
      vec2 off = 0.75 * (na + nb) / max(1.0 + dot(na, nb), 0.1);
      gl_Position.xy += off / uViewport * 2.0 * gl_Position.w;
    }
  }
  #endif
  mat4 M = modelMatrix;
  #ifdef USE_BATCHING
  M = M * batchingMatrix;
  #endif
  #ifdef USE_INSTANCING
  M = M * instanceMatrix;
  #endif
  mat4 Mi = inverse(M);
  vEye = uOrtho ? mat3(Mi) * uCamDir : (Mi * vec4(cameraPosition, 1.0)).xyz;
  #ifdef DNR_UV
  vUv = DNR_UV;
  #else
  vUv = vec2(0.0);
  #endif
}
`;

/**
 * G-buffer fragment shader: attachment 0 = (u, v, neural texture or -1 without uv,
 * renderer + 1; -1 for core surfaces), attachment 1 = local unit view direction.
 */
export const GBUFFER_FRAGMENT = `
uniform bool uOrtho;
uniform float uTex;
uniform float uRid;
in vec3 vLocal;
flat in vec3 vEye;
in vec2 vUv;
#ifdef DNR_EXACT
uniform mat4 uInvMVP;
uniform vec2 uViewport;
flat in vec3 vP0, vP1, vP2;
flat in vec2 vT0, vT1, vT2;
flat in vec2 vS0, vS1, vS2;
flat in float vExact;
float cross2(vec2 a, vec2 b) { return a.x * b.y - a.y * b.x; }
#endif
layout(location = 0) out vec4 gOut0;
layout(location = 1) out vec4 gOut1;
void main() {
  vec2 uv = vUv;
  vec3 P = vLocal;
#ifdef DNR_EXACT
  if (vExact > 0.5) {
    // Is the pixel centre inside the (ungrown) triangle? As the dnr runtime decides it: image
    // coordinates with y down, vertices snapped to 1/256 pixel, the top-left rule for centres
    // exactly on an edge.
    vec2 flipY = vec2(0.0, uViewport.y);
    vec2 p = vec2(gl_FragCoord.x, uViewport.y - gl_FragCoord.y);
    vec2 v[3];
    v[0] = round(vec2(vS0.x, uViewport.y - vS0.y) * 256.0) / 256.0;
    v[1] = round(vec2(vS1.x, uViewport.y - vS1.y) * 256.0) / 256.0;
    v[2] = round(vec2(vS2.x, uViewport.y - vS2.y) * 256.0) / 256.0;
    float area = cross2(v[1] - v[0], v[2] - v[0]);
    if (area == 0.0) discard;
    if (area < 0.0) { vec2 t = v[1]; v[1] = v[2]; v[2] = t; }
    for (int k = 0; k < 3; k++) {
      vec2 a = v[(k + 1) % 3], b = v[(k + 2) % 3];
      vec2 d = b - a;
      float e = cross2(d, p - a);
      bool topLeft = d.y < 0.0 || (d.y == 0.0 && d.x > 0.0);
      if (e < 0.0 || (e == 0.0 && !topLeft)) discard;
    }
  }
  // The point of the triangle on the ray through the pixel centre, in local space: the
  // rasteriser's interpolation follows its subpixel snapping (1/16 pixel in SwiftShader),
  // which moves uv by up to a few hundredths of a pixel.
  vec2 ndc = 2.0 * gl_FragCoord.xy / uViewport - 1.0;
  vec4 q = uInvMVP * vec4(ndc, 0.0, 1.0);
  vec3 onRay = q.xyz / q.w;
  vec3 o = uOrtho ? onRay : vEye;
  vec3 dir = uOrtho ? vEye : onRay - vEye;
  vec3 e1 = vP1 - vP0, e2 = vP2 - vP0;
  vec3 pv = cross(dir, e2);
  float det = dot(e1, pv);
  if (det != 0.0) {
    vec3 tv = o - vP0;
    float b1 = dot(tv, pv) / det;
    float b2 = dot(dir, cross(tv, e1)) / det;
    uv = vT0 + (vT1 - vT0) * b1 + (vT2 - vT0) * b2;
    P = vP0 + e1 * b1 + e2 * b2;
  }
#endif
  vec3 v = uOrtho ? vEye : P - vEye;
  float l = length(v);
  vec3 d = (l > 0.0 && !isinf(l)) ? v / l : vec3(0.0);
  gOut0 = vec4(uv, uTex, uRid);
  gOut1 = vec4(d, 0.0);
}
`;
