// Runs the Khronos glTF-Validator (npm `gltf-validator`) over every sample in
// samples/valid/ (*.glb, *.gltf) and fails on any error or warning.
//
// Install first: npm install --prefix .tools/node gltf-validator
// Usage: node tests/scripts/gltf_validator.mjs [SAMPLES_DIR]   (default samples/valid)
// GLTF_VALIDATOR_PREFIX overrides where the package was installed (default .tools/node).
//
// No exceptions: the extension's binding lives on mesh primitives, so a fallback material
// carries only KHR_materials_unlit and nothing triggers MULTIPLE_EXTENSIONS. Information
// messages (UNSUPPORTED_EXTENSION for EXT_deferred_neural_rendering, UNUSED_OBJECT for the
// bufferViews only the extension references) and hints are printed as counts only.
import { createRequire } from 'node:module';
import fs from 'node:fs';
import path from 'node:path';

const prefix = path.resolve(process.env.GLTF_VALIDATOR_PREFIX ?? '.tools/node');
const require = createRequire(path.join(prefix, 'node_modules', 'noop.js'));
let validator;
try {
  validator = require('gltf-validator');
} catch (e) {
  console.error(`gltf-validator not found under ${prefix}: run npm install --prefix ${prefix} gltf-validator`);
  process.exit(2);
}

const dir = path.resolve(process.argv[2] ?? 'samples/valid');
const files = fs.readdirSync(dir).filter((f) => /\.(glb|gltf)$/i.test(f)).sort();
if (files.length === 0) {
  console.error(`no .glb/.gltf files in ${dir}`);
  process.exit(2);
}

let failed = 0;
for (const name of files) {
  const file = path.join(dir, name);
  const bytes = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(bytes, {
    uri: name,
    maxIssues: 0,
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        const p = path.resolve(dir, decodeURIComponent(uri));
        fs.readFile(p, (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))));
      }),
  });
  const { numErrors, numWarnings, numInfos, numHints, messages } = report.issues;
  // severity: 0 error, 1 warning, 2 info, 3 hint. Count from the messages too, so that a
  // report whose counters and list disagree still fails.
  const errors = Math.max(numErrors, messages.filter((m) => m.severity === 0).length);
  const warnings = Math.max(numWarnings, messages.filter((m) => m.severity === 1).length);
  const bad = errors + warnings;
  console.log(`${bad ? 'FAIL' : 'ok  '} ${name}: ${errors} errors, ${warnings} warnings, ` +
    `${numInfos} infos, ${numHints} hints`);
  for (const m of messages) {
    if (m.severity <= 1 || process.env.VERBOSE) {
      console.log(`     [${m.severity}] ${m.code} ${m.pointer ?? ''}: ${m.message}`);
    }
  }
  if (bad) failed += 1;
}
console.log(`${files.length - failed} passed, ${failed} failed`);
process.exit(failed ? 1 : 0);
