// DNRGLTFPlugin: a GLTFLoader plugin for EXT_deferred_neural_rendering.
//
// Fallback first: the loaded scene keeps every bound primitive's fallback material, so the
// object shows at once. After the root is built, the plugin resolves the asset's buffers
// (parser.getDependency('buffer', i)), and the wasm module (in a worker where possible)
// validates and decodes the extension. Errors by the spec's Conforming Readers rules leave the
// fallback on and log the validator codes; otherwise the DNRNeuralLayer takes the bound
// meshes over.

import { getDecoder } from './decoder.js';

export const EXTENSION = 'EXT_deferred_neural_rendering';

/**
 * Register with `loader.register((parser) => new DNRGLTFPlugin(parser, layer))`. After the
 * load, `gltf.userData.dnr.ready` resolves to 'gpu', 'cpu' (the layer draws) or 'fallback'.
 */
export class DNRGLTFPlugin {
  constructor(parser, layer) {
    this.parser = parser;
    this.layer = layer;
    this.name = EXTENSION;
  }

  afterRoot(result) {
    const parser = this.parser;
    const json = parser.json;
    const bound = [];
    const scenes = result.scenes && result.scenes.length ? result.scenes : [result.scene];
    const seen = new Set();
    for (const s of scenes) {
      s.traverse((o) => {
        if (!o.isMesh || seen.has(o)) return;
        seen.add(o);
        const a = parser.associations.get(o);
        if (!a || a.meshes === undefined || a.primitives === undefined) return;
        const prim = json.meshes?.[a.meshes]?.primitives?.[a.primitives];
        const b = prim?.extensions?.[EXTENSION];
        if (b) {
          bound.push({
            object: o, mesh: a.meshes, primitive: a.primitives,
            binding: { neuralTexture: b.neuralTexture, renderer: b.renderer, texCoord: b.texCoord ?? 0 },
          });
        }
      });
    }
    const rootExt = json.extensions?.[EXTENSION];
    if (!rootExt && bound.length === 0) return null;
    const name = parser.options?.path ? `${parser.options.path}` : 'glTF asset';
    const handle = { name, root: result.scene, bound, status: 'loading', report: null };
    handle.ready = this._load(handle).catch((e) => {
      handle.status = 'fallback';
      console.warn(`dnr: ${name}: the neural layer cannot be used (${e.message}); showing the fallback`);
      return 'fallback';
    });
    result.userData = result.userData || {};
    result.userData.dnr = handle;
    return null;
  }

  async _load(handle) {
    const parser = this.parser;
    const json = parser.json;
    const buffers = await Promise.all((json.buffers || []).map((_, i) => parser.getDependency('buffer', i)));
    const text = new TextEncoder().encode(JSON.stringify(json));
    const decoder = this.layer ? this.layer.decoder : getDecoder();
    const decoded = await decoder.request({ op: 'load', json: text, buffers });
    handle.report = decoded.report;
    if (!decoded.ok) {
      const codes = decoded.report.blocking.length
        ? decoded.report.blocking.join(', ')
        : `not decodable: ${decoded.error}`;
      console.warn(`dnr: ${handle.name}: invalid ${EXTENSION} data (${codes}); showing the fallback`);
      handle.status = 'fallback';
      return 'fallback';
    }
    // The wasm description lists no `supersample` (revision 1.3): take it from the JSON,
    // which the validator has checked (absent: 1).
    const renderers = json.extensions?.[EXTENSION]?.renderers || [];
    decoded.desc.renderers.forEach((r, i) => { r.supersample ??= renderers[i]?.supersample ?? 1; });
    if (!this.layer || handle.bound.length === 0) {
      handle.status = 'fallback';
      return 'fallback';
    }
    handle.status = await this.layer.attach(handle, decoded);
    return handle.status;
  }
}
