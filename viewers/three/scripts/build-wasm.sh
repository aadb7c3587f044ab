#!/usr/bin/env bash
# Builds crates/wasm (dnr-wasm) into viewers/three/wasm/ as a plain ES module
# (`wasm-bindgen --target web`: dnr_wasm.js + dnr_wasm_bg.wasm). Idempotent.
#
# Installs what it needs under the repository's .tools/ (gitignored), from the registries only:
#   - the wasm32-unknown-unknown standard library (`rustup target add`; a rust-toolchain.toml
#     would also pin the channel for the whole workspace, which this does not want);
#   - wasm-bindgen-cli, at exactly the version of the wasm-bindgen crate in
#     crates/wasm/Cargo.toml (the generated glue and the crate must match), via
#     `cargo install --locked`. The npm `wasm-pack` is not used: it downloads binaries.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
root=$(cd "$here/../.." && pwd)
version=$(sed -n 's/^wasm-bindgen = "=\([0-9.]*\)".*/\1/p' "$root/crates/wasm/Cargo.toml")
[ -n "$version" ] || { echo "build-wasm: no exact wasm-bindgen version in crates/wasm/Cargo.toml" >&2; exit 1; }
bindgen="$root/.tools/wasm-bindgen-$version/bin/wasm-bindgen"

if ! rustup target list --installed 2>/dev/null | grep -qx wasm32-unknown-unknown; then
  rustup target add wasm32-unknown-unknown
fi
if ! "$bindgen" --version 2>/dev/null | grep -q " $version\$"; then
  cargo install --locked --root "$root/.tools/wasm-bindgen-$version" wasm-bindgen-cli --version "=$version"
fi

cd "$root"
cargo build -p dnr-wasm --target wasm32-unknown-unknown --profile wasm
"$bindgen" --target web --out-dir "$here/wasm" --out-name dnr_wasm \
  target/wasm32-unknown-unknown/wasm/dnr_wasm.wasm
raw=$(wc -c < "$here/wasm/dnr_wasm_bg.wasm")
gz=$(gzip -9 -c "$here/wasm/dnr_wasm_bg.wasm" | wc -c)
echo "build-wasm: viewers/three/wasm/dnr_wasm_bg.wasm $raw bytes ($gz gzip -9)"
