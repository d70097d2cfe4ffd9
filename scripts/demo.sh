#!/usr/bin/env bash
# The main job on the embedded default: installs what is missing, builds, and deforms the
# built-in demo mesh (a detailed cylinder bent by 120 degrees), writing the result and a
# report to ./out.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/build.sh" -DMESHDEFORM_BUILD_TESTS=OFF -DMESHDEFORM_BUILD_BENCH=OFF
"$root/build/cli/meshdeform-cli" demo --out-dir "${1:-$root/out}"
