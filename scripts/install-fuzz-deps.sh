#!/usr/bin/env bash
# Installs what the clang builds need on top of scripts/install-deps.sh (the fuzz targets,
# scripts/fuzz.sh, and the sanitizer suite, scripts/test-sanitize.sh): clang (Debian 12: clang
# 14) with its runtime libraries, which carry libFuzzer and the sanitizers
# (libclang-rt-14-dev: libclang_rt.fuzzer*.a, libclang_rt.asan*.a, ...), and LLVM's OpenMP for
# the core library when it is built by clang. Idempotent, like install-deps.sh.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/install-deps.sh" clang libclang-rt-14-dev libomp-14-dev
