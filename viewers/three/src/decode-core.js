// The decoder's message handler, shared by the worker (worker.js) and the in-thread fallback
// (decoder.js). `wasm` is the dnr-wasm module after `init()`.
//
// Messages:
//   { op: 'load', json: Uint8Array, buffers: [ArrayBuffer | Uint8Array] }
//     -> { ok, report, error?, asset?, desc?, levels?: [[Float32Array]], tensors?: [{name: Float32Array}] }
//   { op: 'render', asset, fx, fy, cx, cy, camToWorld, width, height } -> { ok, rgba: Float32Array }
//   { op: 'shade', asset, width, height, coverage, prim, uv, viewDir } -> { ok, rgba }
//   { op: 'drop', asset } -> { ok }

export function makeHandler(wasm) {
  const assets = new Map();
  let next = 1;
  return function handle(msg) {
    switch (msg.op) {
      case 'load': {
        const glb = wasm.glbFromParts(msg.json, msg.buffers);
        const report = wasm.validate(glb);
        if (report.blocking.length > 0) {
          return { result: { ok: false, report }, transfer: [] };
        }
        let asset;
        try {
          asset = new wasm.DnrAsset(glb);
        } catch (e) {
          return { result: { ok: false, report, error: String(e && e.message || e) }, transfer: [] };
        }
        const desc = asset.describe();
        const transfer = [];
        const levels = desc.textures.map((t, ti) => t.levels.map((_, li) => {
          const a = asset.levelF32(ti, li);
          transfer.push(a.buffer);
          return a;
        }));
        const tensors = desc.renderers.map((r, ri) => {
          const out = {};
          for (const { name } of r.tensors) {
            const a = asset.tensor(ri, name);
            transfer.push(a.buffer);
            out[name] = a;
          }
          return out;
        });
        const id = next++;
        assets.set(id, asset);
        return { result: { ok: true, report, asset: id, desc, levels, tensors }, transfer };
      }
      case 'render': {
        const a = assets.get(msg.asset);
        if (!a) throw new Error(`no asset ${msg.asset}`);
        const rgba = a.render(msg.fx, msg.fy, msg.cx, msg.cy, msg.camToWorld, msg.width, msg.height);
        return { result: { ok: true, rgba }, transfer: [rgba.buffer] };
      }
      case 'shade': {
        const a = assets.get(msg.asset);
        if (!a) throw new Error(`no asset ${msg.asset}`);
        const rgba = a.shade(msg.width, msg.height, msg.coverage, msg.prim, msg.uv, msg.viewDir);
        return { result: { ok: true, rgba }, transfer: [rgba.buffer] };
      }
      case 'drop': {
        const a = assets.get(msg.asset);
        if (a) a.free();
        assets.delete(msg.asset);
        return { result: { ok: true }, transfer: [] };
      }
      default:
        throw new Error(`unknown decoder operation ${msg.op}`);
    }
  };
}
