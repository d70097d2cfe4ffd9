#!/usr/bin/env bash
# Builds the browser viewer into web_viewer/dist: installs the locked npm dependencies when they
# are missing or the lock file changed (npm ci: exact versions, no downloads beyond the npm
# registry), generates the protobuf code with Debian's protoc and protoc-gen-es, type-checks and
# bundles with Vite. Pass --test to also install Chromium for the browser tests.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/install-viewer-deps.sh" "$@"
cd "$root/web_viewer"
stamp=node_modules/.package-lock.json
if [ ! -f "$stamp" ] || [ package-lock.json -nt "$stamp" ]; then
  npm ci --no-audit --no-fund --loglevel=error
fi
npm run --silent build
