#!/usr/bin/env bash
# The whole test suite again under AddressSanitizer + UndefinedBehaviorSanitizer (GCC), in
# ./build-asan: any memory error, leak or undefined behaviour fails the test that triggered it.
# Every C++ suite runs here, the gRPC server, client, load tester, TLS, recovery and nginx
# scale-out tests included (they drive the instrumented server binary); the benchmarks are left
# out (not tests, and CGAL's long build), and so are the viewer's JavaScript tests (nothing to
# instrument). Pass -DMESHDEFORM_BUILD_SERVER=OFF for a quicker run without gRPC.
# -O1 -g1 keeps the instrumented build quick while the stack traces stay readable.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/install-deps.sh"
cmake -S "$root" -B "$root/build-asan" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1" \
  -DMESHDEFORM_SANITIZE=address,undefined -DMESHDEFORM_BUILD_BENCH=OFF \
  -DMESHDEFORM_BUILD_SERVER=ON -DMESHDEFORM_BUILD_TESTS=ON -DMESHDEFORM_BUILD_CLI=ON "$@" >/dev/null
cmake --build "$root/build-asan" -j"$(nproc)"
[ "${MESHDEFORM_SANITIZE_BUILD_ONLY:-0}" = "1" ] && exit 0  # scripts/test-under-load.sh
# halt_on_error makes UBSan findings fatal (by default it only prints them); LeakSanitizer works
# in this environment, so leaks fail too.
export ASAN_OPTIONS="halt_on_error=1:abort_on_error=0:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
ctest --test-dir "$root/build-asan" --output-on-failure --timeout 1200 -j"$(nproc)"
