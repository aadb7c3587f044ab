// Module worker: decodes and validates assets and draws CPU frames off the main thread.
import init, * as wasm from '../wasm/dnr_wasm.js';
import { makeHandler } from './decode-core.js';

const ready = init({ module_or_path: new URL('../wasm/dnr_wasm_bg.wasm', import.meta.url) })
  .then(() => makeHandler(wasm));

self.onmessage = async (ev) => {
  const { id, msg } = ev.data;
  try {
    const handle = await ready;
    const { result, transfer } = handle(msg);
    self.postMessage({ id, result }, transfer);
  } catch (e) {
    self.postMessage({ id, error: String(e && e.message || e) });
  }
};
