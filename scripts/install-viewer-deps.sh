#!/usr/bin/env bash
# What the browser viewer needs on top of scripts/install-deps.sh: Node.js 20 or newer with npm
# (to build web_viewer/ with Vite), and, with --test, Debian's Chromium for the end-to-end tests
# (driven by playwright-core from web_viewer's npm dependencies; no browser is downloaded).
# Idempotent, like install-deps.sh.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
extra=()
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
  extra+=(nodejs npm)
fi
if [ "${1:-}" = "--test" ]; then
  extra+=(chromium)
fi
"$root/scripts/install-deps.sh" "${extra[@]}"
major="$(node -p 'process.versions.node.split(".")[0]')"
if [ "$major" -lt 20 ]; then
  echo "meshdeform: the viewer needs Node.js 20 or newer (found $(node --version))" >&2
  exit 1
fi
