#!/usr/bin/env bash
# The whole test suite again under AddressSanitizer + UndefinedBehaviorSanitizer, in
# ./build-asan: any memory error, leak or undefined behaviour fails the test that triggered it.
# Every C++ suite runs here, the gRPC server, client, load tester, TLS, recovery and nginx
# scale-out tests included (they drive the instrumented server binary); the benchmarks are left
# out (not tests, and CGAL's long build), and so are the viewer's JavaScript tests (nothing to
# instrument). Pass -DMESHDEFORM_BUILD_SERVER=OFF for a quicker run without gRPC.
#
# Built with clang (MESHDEFORM_SANITIZE_CXX=g++ builds with GCC instead; stage 1 already builds
# everything with GCC). Measured on this project's 2-core machine: the instrumented build takes
# 10.2 min with clang against 18.3 with GCC (GCC's -fsanitize=undefined doubles its compile time
# on Eigen-heavy files), and its first run found two defects in tests that GCC's instrumented
# builds had run clean (a stack use after scope, an enum value outside its range). Its
# instrumented tests run slower (10.7 min against 6.9, most of the difference in its
# stack-use-after-return frames); build and tests together still take 4 min less. -O1 -g1 keeps
# the instrumented build quick while the stack traces stay readable.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cxx="${MESHDEFORM_SANITIZE_CXX:-clang++}"
# MESHDEFORM_SANITIZE_FUZZERS=1 builds the libFuzzer targets here too (clang only), so that the
# test command's fuzz stage runs them from this build instead of a third one
# (scripts/fuzz.sh with MESHDEFORM_FUZZ_BUILD_DIR; tests/fuzz/CMakeLists.txt says what gets
# coverage instrumentation then).
fuzzers=OFF
[ "${MESHDEFORM_SANITIZE_FUZZERS:-0}" = "1" ] && fuzzers=ON
case "$(basename "$cxx")" in
  clang*) "$root/scripts/install-fuzz-deps.sh" ;;  # the project's packages, clang, its runtimes, libomp
  *)
    if [ "$fuzzers" = ON ]; then
      echo "test-sanitize.sh: MESHDEFORM_SANITIZE_FUZZERS=1 needs clang++, not $cxx" >&2
      exit 2
    fi
    "$root/scripts/install-deps.sh"
    ;;
esac
cmake -S "$root" -B "$root/build-asan" -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1" \
  -DMESHDEFORM_SANITIZE=address,undefined -DMESHDEFORM_BUILD_BENCH=OFF \
  -DMESHDEFORM_BUILD_SERVER=ON -DMESHDEFORM_BUILD_TESTS=ON -DMESHDEFORM_BUILD_CLI=ON \
  -DMESHDEFORM_BUILD_FUZZERS="$fuzzers" "$@" >/dev/null
cmake --build "$root/build-asan" -j"$(nproc)"
[ "${MESHDEFORM_SANITIZE_BUILD_ONLY:-0}" = "1" ] && exit 0  # scripts/test-under-load.sh
# halt_on_error makes UBSan findings fatal (by default it only prints them); LeakSanitizer works
# in this environment, so leaks fail too.
export ASAN_OPTIONS="halt_on_error=1:abort_on_error=0:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
ctest --test-dir "$root/build-asan" --output-on-failure --timeout 1200 -j"$(nproc)"
