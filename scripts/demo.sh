#!/usr/bin/env bash
# The main job on the embedded default: installs what is missing, builds the server and the
# browser viewer, starts meshdeform-server on loopback with a demo session (the detailed cylinder,
# 4,802 vertices, its fixed and handle regions already set) and prints the viewer's URLs.
# Open the edit link and drag the orange handle; open the watch link in a second window to see
# the edits live. Ctrl-C stops the server.
#
#   ./scripts/demo.sh                # ports 50051 (gRPC) and 8080 (viewer, gRPC-Web, /metrics)
#   MESHDEFORM_HTTP_PORT=9000 ./scripts/demo.sh
#   ./scripts/demo.sh --check        # start, check that the viewer and the session answer, stop
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
grpc_port="${MESHDEFORM_GRPC_PORT:-50051}"
http_port="${MESHDEFORM_HTTP_PORT:-8080}"
sample="${MESHDEFORM_DEMO_SAMPLE:-cylinder}"

# A fresh ./build skips the tests and benchmarks (a quicker first demo); an existing one keeps
# its configuration (a developer's test build is not switched off behind their back).
fresh=()
[ -f "$root/build/CMakeCache.txt" ] || fresh=(-DMESHDEFORM_BUILD_TESTS=OFF -DMESHDEFORM_BUILD_BENCH=OFF)
"$root/scripts/build.sh" -DMESHDEFORM_BUILD_SERVER=ON -DMESHDEFORM_BUILD_CLI=ON "${fresh[@]}"
"$root/scripts/build-viewer.sh"

server="$root/build/server/transport/meshdeform-server"
client="$root/build/client_cpp/meshdeform-client"
log="$(mktemp -t meshdeform-demo.XXXXXX.log)"
"$server" --listen "127.0.0.1:$grpc_port" --http-listen "127.0.0.1:$http_port" \
  --web-root "$root/web_viewer/dist" 2>"$log" &
server_pid=$!
trap 'kill "$server_pid" 2>/dev/null || true; wait "$server_pid" 2>/dev/null || true' EXIT
trap 'exit 0' INT TERM

for _ in $(seq 1 100); do  # at most 10 s
  grep -q '"event":"http_listening"' "$log" && break
  if ! kill -0 "$server_pid" 2>/dev/null; then cat "$log" >&2; exit 1; fi
  sleep 0.1
done
grep -q '"event":"http_listening"' "$log" || { cat "$log" >&2; echo "server did not start" >&2; exit 1; }

created="$("$client" --server "127.0.0.1:$grpc_port" create --sample "$sample")"
field() { node -e 'const j=JSON.parse(process.argv[1]); process.stdout.write(String(j[process.argv[2]]))' "$created" "$1"; }
session="$(field session_id)"
edit="$(field edit_token)"
view="$(field view_token)"
groups="$(node -e 'process.stdout.write(JSON.stringify(JSON.parse(process.argv[1]).suggested_groups))' "$created")"
MESHDEFORM_TOKEN="$edit" "$client" --server "127.0.0.1:$grpc_port" handles --session "$session" \
  --groups "$groups" >/dev/null

base="http://127.0.0.1:$http_port/"
cat <<TEXT

meshdeform is running (server log: $log)
  edit the demo mesh:   ${base}#session=$session&token=$edit
  watch it live:        ${base}#session=$session&token=$view
  a new session:        ${base}?sample=bumpy_plane   (samples: cylinder bar cactus bumpy_plane, *_small)
  metrics:              ${base}metrics
Press Ctrl-C to stop.
TEXT

if [ "${1:-}" = "--check" ]; then
  command -v curl >/dev/null || "$root/scripts/install-deps.sh" curl
  curl -fsS "$base" | grep -q '<html' && echo "check: viewer page served"
  curl -fsS "${base}healthz" >/dev/null && echo "check: healthz ok"
  MESHDEFORM_TOKEN="$view" "$client" --server "127.0.0.1:$grpc_port" info --session "$session" \
    >/dev/null && echo "check: demo session answers"
  exit 0
fi
wait "$server_pid"
