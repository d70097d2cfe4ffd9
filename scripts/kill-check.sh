#!/usr/bin/env bash
# Kill check: a server-driving test binary killed with SIGKILL mid-run must leave nothing behind.
# Runs a test that holds an idle meshdeform-server (tests/client/kill_check_target_test.cpp), waits
# (bounded) until it says the server is up, SIGKILLs the test, then checks, each within a bound,
# that (1) the server is gone (test::ChildProcess asks for PR_SET_PDEATHSIG) and (2) nothing holds
# the test's stdout open (ctest would otherwise wait on that pipe for minutes). An idle server is
# the hard case: one with calls in flight dies anyway of SIGPIPE on its next log line.
#
#   scripts/kill-check.sh [BUILD_DIR=build]     (after scripts/build.sh with tests)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${1:-$root/build}"
binary="$build/tests/meshdeform_client_tests"
[ -x "$binary" ] || { echo "kill-check: $binary is missing (build the tests first)" >&2; exit 2; }

scratch="$(mktemp -d)"
cleanup() {
  [ -n "${test_pid:-}" ] && kill -9 "$test_pid" 2>/dev/null || true
  [ -n "${reader_pid:-}" ] && kill "$reader_pid" 2>/dev/null || true
  rm -rf "$scratch"
}
trap cleanup EXIT

# Alive = exists and is not a zombie (an unreaped zombie holds no resources).
alive() {
  local state
  state="$(awk '/^State:/ {print $2}' "/proc/$1/status" 2>/dev/null || true)"
  [ -n "$state" ] && [ "$state" != "Z" ]
}

mkfifo "$scratch/stdout"
# The reader ends when the last writer of the test's stdout closes it.
( cat "$scratch/stdout" > "$scratch/log"; touch "$scratch/eof" ) &
reader_pid=$!
"$binary" --gtest_also_run_disabled_tests \
  --gtest_filter='KillCheckTarget.DISABLED_HoldsAnIdleServerUntilKilled' > "$scratch/stdout" 2>&1 &
test_pid=$!

servers=""
for _ in $(seq 1 1200); do  # at most 120 s for the test to start its server
  if grep -q "kill-check-target: server .* ready" "$scratch/log" 2>/dev/null; then
    servers="$(pgrep -P "$test_pid" -f meshdeform-server || true)"
    [ -n "$servers" ] && break
  fi
  alive "$test_pid" || break
  sleep 0.1
done
if [ -z "$servers" ]; then
  echo "kill-check: the test never started a server; its output:" >&2
  kill -9 "$test_pid" 2>/dev/null || true
  sleep 1
  cat "$scratch/log" >&2 || true
  exit 1
fi
kill -9 "$test_pid"
wait "$test_pid" 2>/dev/null || true
test_pid=""

left=""
for _ in $(seq 1 100); do  # servers gone within 10 s
  left=""
  for pid in $servers; do alive "$pid" && left="$left $pid"; done
  [ -z "$left" ] && break
  sleep 0.1
done
if [ -n "$left" ]; then
  echo "kill-check: FAILED: server process(es)$left outlived the killed test" >&2
  kill -9 $left 2>/dev/null || true
  exit 1
fi

for _ in $(seq 1 100); do  # stdout closed within 10 s
  [ -e "$scratch/eof" ] && break
  sleep 0.1
done
if [ ! -e "$scratch/eof" ]; then
  echo "kill-check: FAILED: something still holds the killed test's stdout open" >&2
  exit 1
fi
echo "kill-check: passed (killed the test with server(s) $servers running; all gone, stdout closed)" >&2
