#!/usr/bin/env bash
# The whole test suite: installs what is missing, builds everything (the benchmarks too, so
# they cannot rot) and runs CTest.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/build.sh" -DMESHDEFORM_BUILD_TESTS=ON -DMESHDEFORM_BUILD_BENCH=ON -DMESHDEFORM_BUILD_CLI=ON \
  -DMESHDEFORM_BUILD_SERVER=ON
ctest --test-dir "$root/build" --output-on-failure --timeout 600 -j"$(nproc)"
