#!/usr/bin/env bash
# The whole test suite, in three stages; any failure fails the run:
#  1. installs what is missing, builds everything in ./build (the benchmarks too, so they cannot
#     rot) and the browser viewer (web_viewer/dist), and runs CTest: the C++ suites, the viewer's
#     vitest tests and its end-to-end tests in headless Chromium; then the kill check
#     (scripts/kill-check.sh: a SIGKILLed test leaves no server process behind);
#  2. every C++ test again under ASan + UBSan, the gRPC suites included (scripts/test-sanitize.sh,
#     ./build-asan; no benchmarks, no JavaScript);
#  3. a short bounded fuzz run of every parser (scripts/fuzz.sh, clang + libFuzzer),
#     MESHDEFORM_FUZZ_SECONDS per target (default 10), with the targets built in stage 2's
#     ./build-asan (./build-fuzz when stage 2 is skipped).
# MESHDEFORM_SKIP_SANITIZE=1 skips stage 2, MESHDEFORM_FUZZ_SECONDS=0 skips stage 3 (local loops).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

stage() { echo "== test.sh: $1 ($(( SECONDS - start ))s)" >&2; }
start=$SECONDS

"$root/scripts/build-viewer.sh" --test
# -Werror: both compilers' builds stay free of warnings (MESHDEFORM_WERROR; docs/testing.md).
"$root/scripts/build.sh" -DMESHDEFORM_BUILD_TESTS=ON -DMESHDEFORM_BUILD_BENCH=ON -DMESHDEFORM_BUILD_CLI=ON \
  -DMESHDEFORM_BUILD_SERVER=ON -DMESHDEFORM_VIEWER_TESTS=ON -DMESHDEFORM_WERROR=ON
ctest --test-dir "$root/build" --output-on-failure --timeout 600 -j"$(nproc)"
# A test binary killed with SIGKILL mid-run leaves no server behind and no open stdout.
"$root/scripts/kill-check.sh" "$root/build"
stage "stage 1 (build + tests + kill check) done"

fuzz_seconds="${MESHDEFORM_FUZZ_SECONDS:-10}"
fuzzers=0  # 1: stage 2 built the fuzz targets
if [ "${MESHDEFORM_SKIP_SANITIZE:-0}" != "1" ]; then
  # The fuzz targets are built in the same instrumented build (one clang build, not two).
  # (Not with MESHDEFORM_SANITIZE_CXX=g++: libFuzzer is clang's; stage 3 then builds its own.)
  # -Werror with clang, the default; GCC's instrumented build is a local option and is left out.
  werror=()
  case "$(basename "${MESHDEFORM_SANITIZE_CXX:-clang++}")" in
    clang*)
      [ "$fuzz_seconds" != "0" ] && fuzzers=1
      werror=(-DMESHDEFORM_WERROR=ON)
      ;;
  esac
  MESHDEFORM_SANITIZE_FUZZERS=$fuzzers "$root/scripts/test-sanitize.sh" "${werror[@]}"
  stage "stage 2 (ASan + UBSan tests) done"
fi

if [ "$fuzz_seconds" != "0" ]; then
  if [ "$fuzzers" = 1 ]; then
    MESHDEFORM_FUZZ_BUILD_DIR="$root/build-asan" "$root/scripts/fuzz.sh" "$fuzz_seconds"
  else
    "$root/scripts/fuzz.sh" "$fuzz_seconds"
  fi
  stage "stage 3 (fuzz, ${fuzz_seconds}s per target) done"
fi
