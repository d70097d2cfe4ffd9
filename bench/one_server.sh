# Sourced by the single-server bench scripts (run_loadtest.sh, run_multires_server.sh) from the
# repository root with $build set: checks the binaries, sets $server, $loadtest and $out
# (bench/results), and runs one fresh meshdeform-server on a loopback port at a time. The caller
# sets $log (a file for the server's stderr) and traps `stop_server_if_running` on EXIT.
server="$build/server/transport/meshdeform-server"
loadtest="$build/client_cpp/loadtest/meshdeform-loadtest"
out=bench/results
for binary in "$server" "$loadtest"; do
  [[ -x "$binary" ]] || { echo "missing $binary: run ./scripts/build.sh first" >&2; exit 2; }
done
mkdir -p "$out"
pid=""
port=""

# start_server FLAGS...: starts the server on 127.0.0.1:0 and sets $port from its log.
start_server() {
  "$server" --listen 127.0.0.1:0 "$@" 2>"$log" &
  pid=$!
  for _ in $(seq 1 100); do
    port=$(grep -o '"event":"listening".*"port":[0-9]*' "$log" | grep -o '[0-9]*$' || true)
    [[ -n "$port" ]] && return 0
    sleep 0.1
  done
  echo "server did not start:" >&2; cat "$log" >&2; exit 1
}

stop_server() { kill -TERM "$pid"; wait "$pid" || true; pid=""; }
stop_server_if_running() { [[ -n "$pid" ]] && kill "$pid" 2>/dev/null || true; }
