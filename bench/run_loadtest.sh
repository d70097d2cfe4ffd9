#!/usr/bin/env bash
# Runs the service load benchmarks of issue 4 against a fresh meshdeform-server on loopback and
# writes bench/results/loadtest*.{md,json}:
#   1. the issue's figure: 16 sessions x cylinder (4,802 vertices) x 10 Hz x 2 watchers x 60 s,
#      with 2 and with 1 outer iteration per move;
#   2. what this machine sustains: the same with the rate lowered to 4 Hz;
#   3. one warm move on the 40,401-vertex bumpy plane (1 session, 20 moves back to back).
# Usage: bench/run_loadtest.sh [BUILD_DIR] (default ./build; build it with ./scripts/build.sh).
# Takes about 4 minutes. Run it on a quiet machine: the figures are latencies.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
source bench/one_server.sh  # $server, $loadtest, $out; start_server / stop_server

log=$(mktemp)
# start_server / stop_server (bench/one_server.sh): a fresh server per run, memory from zero
cleanup() { stop_server_if_running; rm -f "$log"; }
trap cleanup EXIT

run() {  # run NAME SERVER_FLAGS... -- LOADTEST_FLAGS...
  local name=$1; shift
  local server_flags=()
  while [[ $1 != -- ]]; do server_flags+=("$1"); shift; done
  shift
  start_server "${server_flags[@]}"
  echo "== $name"
  "$loadtest" --server "127.0.0.1:$port" "$@" --json "$out/$name.json" --markdown "$out/$name.md"
  stop_server
}

run loadtest_16x10hz_it2 -- --sessions 16 --sample cylinder --rate 10 --iterations 2 --watchers 2 --duration 60
run loadtest_16x10hz_it1 -- --sessions 16 --sample cylinder --rate 10 --iterations 1 --watchers 2 --duration 60
run loadtest_16x4hz_it1 -- --sessions 16 --sample cylinder --rate 4 --iterations 1 --watchers 2 --duration 60
run loadtest_plane_warm_move --refine-budget 0 -- --sessions 1 --sample bumpy_plane --rate 0 --moves 20 --iterations 2 --watchers 0 --duration 120
echo "wrote $out/loadtest_*.{md,json}"
