// Where the wasm module runs: in a module worker when the page can start one, else on the
// main thread. Both answer the same messages (decode-core.js).

let shared = null;

/** The process-wide decoder (one worker for every asset). */
export function getDecoder(options = {}) {
  if (!shared || options.fresh) shared = new Decoder(options);
  return shared;
}

export class Decoder {
  constructor({ worker = true } = {}) {
    this.pending = new Map();
    this.nextId = 1;
    this.worker = null;
    this.local = null;
    this.where = 'main thread';
    if (worker && typeof Worker !== 'undefined') {
      try {
        this.worker = new Worker(new URL('./worker.js', import.meta.url), { type: 'module' });
        this.worker.onmessage = (ev) => this._answer(ev.data);
        this.worker.onerror = (ev) => this._workerFailed(ev);
        this.where = 'worker';
      } catch (e) {
        this.worker = null;
      }
    }
  }

  _answer({ id, result, error }) {
    const p = this.pending.get(id);
    if (!p) return;
    this.pending.delete(id);
    if (error !== undefined) p.reject(new Error(error));
    else p.resolve(result);
  }

  // A worker that cannot start (module workers refused, script blocked) hands its queue to
  // the main thread.
  _workerFailed(ev) {
    if (ev && ev.preventDefault) ev.preventDefault();
    const queue = [...this.pending.entries()];
    this.worker = null;
    this.where = 'main thread';
    this.pending.clear();
    for (const [, p] of queue) this._runLocal(p.msg).then(p.resolve, p.reject);
  }

  async _localHandler() {
    if (!this.local) {
      this.local = (async () => {
        const wasm = await import('../wasm/dnr_wasm.js');
        await wasm.default({ module_or_path: new URL('../wasm/dnr_wasm_bg.wasm', import.meta.url) });
        const { makeHandler } = await import('./decode-core.js');
        return makeHandler(wasm);
      })();
    }
    return this.local;
  }

  async _runLocal(msg) {
    const handle = await this._localHandler();
    return handle(msg).result;
  }

  /** Sends one message; resolves with the handler's result. */
  request(msg, transfer = []) {
    if (!this.worker) return this._runLocal(msg);
    const id = this.nextId++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject, msg });
      this.worker.postMessage({ id, msg }, transfer);
    });
  }
}
