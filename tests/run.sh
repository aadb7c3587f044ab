#!/usr/bin/env bash
# The one command that runs every test (README quick start, .ci/run).
#
# Installs what the tests need beyond cargo, idempotently, under .tools/ (gitignored):
#   - the Khronos glTF-Validator (npm `gltf-validator`),
#   - the reference OpenEXR library (PyPI `OpenEXR`) and `jsonschema` for the spec examples.
# Then runs the Rust tests and the cross-implementation checks on samples/. The first step,
# which needs only git, checks that no tracked file names an absolute path of a machine.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
tools=$root/.tools
export CARGO_TERM_COLOR=never
# One clean build per run: incremental caches would only double the disk it takes.
export CARGO_INCREMENTAL=0

step() { printf '\n== %s\n' "$*"; }

step "no absolute machine paths in tracked files"
bash tests/scripts/check_machine_paths.sh

step "tools"
if [ ! -f "$tools/node/node_modules/gltf-validator/package.json" ]; then
  npm install --prefix "$tools/node" --no-audit --no-fund --loglevel=error gltf-validator@2.0.0-dev.3.10
fi
if ! "$tools/venv/bin/python" -c 'import OpenEXR, numpy, jsonschema' 2>/dev/null; then
  python3 -m venv "$tools/venv"
  "$tools/venv/bin/pip" install -q --disable-pip-version-check "OpenEXR==3.5.3" numpy "jsonschema==4.26.0"
fi

step "cargo test (workspace)"
mkdir -p target
cargo build -p dnr-cli
cargo test --workspace --no-fail-fast 2>&1 | tee "$root/target/cargo-test.log"

step "crate documentation builds without warnings"
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --workspace

step "release tests (bake end to end)"
cargo test --release -p dnr-bake --features e2e --test e2e_bake 2>&1 | tee -a "$root/target/cargo-test.log"

step "Khronos glTF-Validator on samples/valid"
NODE_PATH="$tools/node/node_modules" node tests/scripts/gltf_validator.mjs samples/valid

step "Khronos glTF-Validator on an asset baked from a UV-less PLY (phone-like COLMAP capture)"
phone=$root/target/phone-capture
rm -rf "$phone" && mkdir -p "$phone/assets"
cargo run -q -p dnr-bake --example make_phone_capture -- "$phone" --size 240x180 --frames 10 --segments 16
cargo run -q -p dnr-bake -- "$phone/phone" -o "$phone/assets/phone.glb" --preset fast --steps 30
NODE_PATH="$tools/node/node_modules" node tests/scripts/gltf_validator.mjs "$phone/assets"

step "reference OpenEXR decode of every EXR level in samples/valid"
"$tools/venv/bin/python" tests/scripts/check_exr.py samples/valid

step "reference PNG decode and dequantisation of every quantised level in samples/valid"
"$tools/venv/bin/python" tests/scripts/check_png_levels.py samples/valid

step "spec examples against the JSON Schema"
"$tools/venv/bin/python" spec/EXT_deferred_neural_rendering/check_examples.py

step "browser conformance of the three.js plugin (viewers/three: npm test)"
# Installs chromium (apt) and the node packages, builds the wasm module, bakes a small duck.
cargo build -p dnr-bake
(cd viewers/three && npm test)

echo
echo "all test steps passed"
