#!/usr/bin/env bash
# The server-driving suites on a busy machine: both cores saturated by a bounded CPU hog while
# CTest runs the suites that start servers (service, transport, client, loadtest, recovery,
# scaleout) from stage 1's build (./build) and from the sanitizer build (./build-asan), ROUNDS
# times in random order. Any failure fails the run. Tests must not depend on wall-clock speed,
# so they pass here as on a quiet machine, only slower. Brings both builds up to date first.
#
#   scripts/test-under-load.sh [ROUNDS=3]
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
rounds="${1:-3}"
[[ "$rounds" =~ ^[0-9]+$ ]] || { echo "usage: $0 [ROUNDS]" >&2; exit 2; }
labels='service|transport|client|loadtest|recovery|scaleout'

# Both builds brought up to date (incremental; a no-op when nothing changed), so that the
# suites under load are those of the checkout, not of an older build left in place.
if [ -f "$root/build/CMakeCache.txt" ]; then
  cmake --build "$root/build" -j"$(nproc)"
else
  "$root/scripts/build.sh" -DMESHDEFORM_BUILD_TESTS=ON -DMESHDEFORM_BUILD_SERVER=ON
fi
MESHDEFORM_SANITIZE_BUILD_ONLY=1 "$root/scripts/test-sanitize.sh"

hogs=()
stop_hogs() {
  for pid in "${hogs[@]}"; do kill "$pid" 2>/dev/null || true; done
  hogs=()
}
trap stop_hogs EXIT
# One busy loop per core, each ending by itself after the bound even if this script dies.
start_hogs() {
  local limit="$1"
  for _ in $(seq 1 "$(nproc)"); do
    timeout "$limit" sh -c 'while :; do :; done' &
    hogs+=("$!")
  done
}

export ASAN_OPTIONS="halt_on_error=1:abort_on_error=0:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
start=$SECONDS
for round in $(seq 1 "$rounds"); do
  for build in build build-asan; do
    echo "== test-under-load: round $round/$rounds, $build, $(nproc) cores hogged" >&2
    start_hogs 3600
    ctest --test-dir "$root/$build" -L "$labels" --schedule-random --timeout 1800 \
      -j"$(nproc)" --output-on-failure
    stop_hogs
  done
done
echo "test-under-load: $rounds rounds passed under load in $(( SECONDS - start )) s" >&2
