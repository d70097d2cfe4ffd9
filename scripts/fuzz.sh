#!/usr/bin/env bash
# Builds the libFuzzer targets (clang, ASan + UBSan, ./build-fuzz) and runs each for a bounded
# time on a scratch copy of its committed seed corpus (tests/fuzz/corpus/<target>/, never written
# to). Fails on the first crash, sanitizer report, leak, timeout or out-of-memory; the reproducer
# is kept in build-fuzz/findings/<target>/. The corpus holds every regression input (files named
# regress-*: minimised findings and the hostile headers of issue 11), so each run replays them.
#
# A single input may take at most 2 s (-timeout): work bounded by bytes means no input of
# -max_len bytes may take longer, so a slow input is a finding, not noise (the 139-byte PLY that
# declared 2e9 property-less rows took over 60 s before the readers were fixed).
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET=10] [TARGET...]
#
# MESHDEFORM_FUZZ_BUILD_DIR=DIR runs the targets already built in DIR (the test command's
# sanitizer build, scripts/test-sanitize.sh with MESHDEFORM_SANITIZE_FUZZERS=1) instead of
# configuring and building ./build-fuzz.
#
# The test command runs 10 s per target. Before a change to a parser lands, run the long campaign,
# 10 minutes per target, one per core at a time (12 targets: about 1 hour on two cores), and
# report it in docs/testing.md:
#
#   scripts/fuzz.sh 600
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
seconds="${1:-10}"
shift || true
[[ "$seconds" =~ ^[0-9]+$ ]] || { echo "usage: $0 [SECONDS_PER_TARGET] [TARGET...]" >&2; exit 2; }

if [ -n "${MESHDEFORM_FUZZ_BUILD_DIR:-}" ]; then
  build="$MESHDEFORM_FUZZ_BUILD_DIR"
  [ -d "$build/tests/fuzz" ] || {
    echo "fuzz.sh: $build has no fuzz targets (build it with scripts/test-sanitize.sh and MESHDEFORM_SANITIZE_FUZZERS=1)" >&2
    exit 2
  }
else
  "$root/scripts/install-fuzz-deps.sh"
  build="$root/build-fuzz"
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_COMPILER=clang++ -DMESHDEFORM_BUILD_FUZZERS=ON \
    -DMESHDEFORM_BUILD_TESTS=OFF -DMESHDEFORM_BUILD_CLI=OFF -DMESHDEFORM_BUILD_BENCH=OFF \
    -DMESHDEFORM_BUILD_SERVER=ON >/dev/null  # for the protobuf code of fuzz_request only
  cmake --build "$build" -j"$(nproc)" --target meshdeform_fuzzers
fi

if [ $# -gt 0 ]; then
  targets=("$@")
else
  targets=(fuzz_mesh_obj fuzz_mesh_off fuzz_mesh_ply fuzz_mesh_stl fuzz_mesh_glb fuzz_mesh_gltf
           fuzz_sel fuzz_def fuzz_edit_spec fuzz_clean fuzz_request fuzz_state fuzz_update_delta)
fi

scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
export ASAN_OPTIONS="halt_on_error=1:detect_leaks=1:allocator_may_return_null=0"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
# One target per core at a time (a libFuzzer process uses one): each batch runs side by side.
run_target() {
  local target="$1" corpus="$scratch/$1" findings="$build/findings/$1"
  mkdir -p "$corpus" "$findings"
  cp -r "$root/tests/fuzz/corpus/$target/." "$corpus/"
  # One process, bounded by time; -timeout / -rss_limit_mb turn hangs and blow-ups into failures.
  "$build/tests/fuzz/$target" -max_total_time="$seconds" -timeout=2 -rss_limit_mb=2048 \
    -max_len=4096 -print_final_stats=1 -artifact_prefix="$findings/" "$corpus" \
    >"$scratch/$target.log" 2>&1
}
batch=$(nproc)
failed=0
for ((i = 0; i < ${#targets[@]}; i += batch)); do
  names=("${targets[@]:i:batch}")
  pids=()
  for target in "${names[@]}"; do
    echo "fuzz: $target for ${seconds}s" >&2
    run_target "$target" &
    pids+=($!)
  done
  for j in "${!names[@]}"; do
    target="${names[$j]}"
    if ! wait "${pids[$j]}"; then
      tail -n 60 "$scratch/$target.log" >&2 || true
      echo "fuzz: $target FAILED; reproducer in $build/findings/$target/" >&2
      failed=1
      continue
    fi
    echo -n "fuzz: $target: " >&2
    grep -E '^stat::number_of_executed_units|^Done' "$scratch/$target.log" | tr '\n' ' ' >&2 || true
    echo >&2
  done
  [ "$failed" = 0 ] || exit 1
done
echo "fuzz: all ${#targets[@]} targets ran ${seconds}s each without a finding" >&2
