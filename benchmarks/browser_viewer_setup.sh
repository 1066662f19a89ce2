#!/usr/bin/env bash
# What tests/output/test_browser_viewer.py needs: Debian's chromium (headless, WebGL through
# SwiftShader) and the npm package gsplat (huggingface's gsplat.js) in .cache/browser-viewer/,
# outside the tracked tree. Without them the test skips and says which is missing.
#   bash benchmarks/browser_viewer_setup.sh [DIR]     (DIR: where node_modules goes)
# The chromium package is installed when run as root; otherwise the apt-get command is printed.
set -euo pipefail
cd "$(dirname "$0")/.."

# The version the test's PSNR floors were measured with (docs/output.md); another may render differently.
GSPLAT_VERSION=1.2.9
DIR="${1:-${FIXER4D_BROWSER_VIEWER:-.cache/browser-viewer}}"

if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ]; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  else
    echo "chromium is missing; run: sudo apt-get install -y chromium" >&2
  fi
fi

command -v npm >/dev/null 2>&1 || { echo "npm is missing; run: sudo apt-get install -y npm" >&2; exit 1; }
mkdir -p "$DIR"
[ -f "$DIR/package.json" ] || echo '{"private": true}' > "$DIR/package.json"
npm install --prefix "$DIR" --no-audit --no-fund --loglevel=error "gsplat@$GSPLAT_VERSION"

command -v chromium >/dev/null 2>&1 && chromium --version
echo "gsplat $(node -p "require(require('path').resolve('$DIR/node_modules/gsplat/package.json')).version") in $DIR"
