#!/usr/bin/env bash
# Installs what the browser tests need, idempotently: Debian's chromium (apt; headless,
# software WebGL2 through SwiftShader) and the node packages of package-lock.json
# (three, playwright-core: neither downloads a browser).
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
if ! command -v chromium >/dev/null 2>&1 && [ -z "${CHROMIUM:-}" ]; then
  if [ "$(id -u)" != 0 ]; then sudo=sudo; else sudo=; fi
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi
if [ ! -f "$here/node_modules/three/package.json" ] || [ ! -f "$here/node_modules/playwright-core/package.json" ] \
   || [ "$here/package-lock.json" -nt "$here/node_modules/.package-lock.json" ]; then
  (cd "$here" && npm ci --no-audit --no-fund --loglevel=error)
fi
