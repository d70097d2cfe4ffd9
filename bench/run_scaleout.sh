#!/usr/bin/env bash
# Scale-out benchmark of issues 6 and 16: the same load (meshdeform-loadtest, 8 sessions x
# cylinder (4,802 vertices) x 4 Hz x 1 outer iteration x 1 watcher) against
#   1. one meshdeform-server, directly (with --state-dir, so every run persists every revision);
#   2. nginx (docker/nginx.conf.template rendered for loopback, as tests/scaleout does) in front
#      of 1 replica (the proxy's own cost) and of 3 replicas sharing one --state-dir;
#   3. nginx in front of 3 replicas on one redis-server (--redis, appendonly yes, appendfsync
#      always: every revision on disk before it is acknowledged, as with --state-dir), with the
#      template's session hash (affinity as a cache) and with round robin (the hash lines taken
#      out: every call may land on another replica);
# and writes bench/results/scaleout_{single,nginx1,nginx3,redis3_hash,redis3_rr}.{md,json} (the
# load tester's own reports) and the comparison bench/results/scaleout.{md,json}. Everything
# runs on 127.0.0.1.
# Usage: bench/run_scaleout.sh [BUILD_DIR] [DURATION_S] (defaults ./build, 30).
# Needs nginx (/usr/sbin/nginx, or $NGINX), redis-server (or $REDIS_SERVER) and python3. Takes
# about 5 x DURATION_S + 30 s.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
duration="${2:-30}"
server="$build/server/transport/meshdeform-server"
loadtest="$build/client_cpp/loadtest/meshdeform-loadtest"
nginx="${NGINX:-/usr/sbin/nginx}"
redis="${REDIS_SERVER:-/usr/bin/redis-server}"
out=bench/results
for binary in "$server" "$loadtest" "$nginx" "$redis"; do
  [[ -x "$binary" ]] || { echo "missing $binary (build with ./scripts/build.sh; apt-get install nginx redis-server)" >&2; exit 2; }
done
mkdir -p "$out"
load=(--sessions 8 --sample cylinder --rate 4 --iterations 1 --watchers 1 --duration "$duration")

work=$(mktemp -d /tmp/meshdeform-scaleout-bench-XXXXXX)
chmod 0755 "$work"  # nginx's workers run unprivileged when this runs as root
pids=()
nginx_pid=""
redis_pid=""
cleanup() {
  if [[ -n "$redis_pid" ]]; then kill -TERM "$redis_pid" 2>/dev/null || true; wait "$redis_pid" 2>/dev/null || true; fi
  if [[ -n "$nginx_pid" ]]; then
    kill -TERM "$nginx_pid" 2>/dev/null || true
    for _ in $(seq 1 50); do kill -0 "$nginx_pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$nginx_pid" 2>/dev/null || true
  fi
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

# start_server NAME FLAGS...: sets $port and $http_port; the log is $work/NAME.log.
start_server() {
  local name=$1; shift
  "$server" --listen 127.0.0.1:0 --http-listen 127.0.0.1:0 "$@" 2>"$work/$name.log" &
  pids+=($!)
  port=""; http_port=""
  for _ in $(seq 1 100); do
    port=$(grep -so '"event":"listening".*"port":[0-9]*' "$work/$name.log" | grep -o '[0-9]*$' || true)
    http_port=$(grep -so '"event":"http_listening".*"port":[0-9]*' "$work/$name.log" | grep -o '[0-9]*$' || true)
    [[ -n "$port" && -n "$http_port" ]] && return 0
    sleep 0.1
  done
  echo "server $name did not start:" >&2; cat "$work/$name.log" >&2; exit 1
}
stop_servers() {
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  pids=()
}
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

# ---- 1. one server, directly
start_server single --state-dir "$work/state-single"
echo "== single server on 127.0.0.1:$port"
"$loadtest" --server "127.0.0.1:$port" "${load[@]}" \
  --json "$out/scaleout_single.json" --markdown "$out/scaleout_single.md"
stop_servers

# ---- 2. nginx in front of N replicas on one state directory (N = 1: the proxy's own cost)
# run_nginx N NAME [hash|rr] [STATE FLAGS...]: replicas started with STATE FLAGS (default: one
# shared --state-dir); rr takes the template's two hash lines out (round robin).
run_nginx() {
  local replicas=$1 name=$2 balance=${3:-hash} grpc_servers="" http_servers="" i
  shift 3 || shift $#
  local state=("$@")
  rm -rf "$work/state-shared" "$work/nginx-temp" "$work/access.log"
  [[ ${#state[@]} -gt 0 ]] || state=(--state-dir "$work/state-shared")
  for i in $(seq 1 "$replicas"); do
    start_server "replica$i" "${state[@]}"
    grpc_servers+="server 127.0.0.1:$port; "
    http_servers+="server 127.0.0.1:$http_port; "
  done
  nginx_grpc=$(free_port); nginx_http=$(free_port)
  mkdir -p "$work/nginx-temp"
  MESHDEFORM_GRPC_SERVERS="$grpc_servers" MESHDEFORM_HTTP_SERVERS="$http_servers" \
  NGINX_GRPC_LISTEN="127.0.0.1:$nginx_grpc" NGINX_HTTP_LISTEN="127.0.0.1:$nginx_http" \
  NGINX_TEMP_DIR="$work/nginx-temp" NGINX_ACCESS_LOG="$work/access.log" NGINX_ERROR_LOG="$work/error.log" \
  BALANCE="$balance" python3 - docker/nginx.conf.template "$work/nginx.conf" <<'PY'
import os, sys
names = ["MESHDEFORM_GRPC_SERVERS", "MESHDEFORM_HTTP_SERVERS", "NGINX_GRPC_LISTEN",
         "NGINX_HTTP_LISTEN", "NGINX_TEMP_DIR", "NGINX_ACCESS_LOG", "NGINX_ERROR_LOG"]
text = open(sys.argv[1]).read()
if os.environ["BALANCE"] == "rr":
    hash_line = "    hash $meshdeform_affinity;\n"
    assert text.count(hash_line) == 2, "the template's upstream blocks changed"
    text = text.replace(hash_line, "")
for name in names:
    assert "${" + name + "}" in text, name
    text = text.replace("${" + name + "}", os.environ[name])
open(sys.argv[2], "w").write(text)
PY
  "$nginx" -p "$work/" -c "$work/nginx.conf" -e "$work/error.log" \
    -g "daemon off; pid $work/nginx.pid;" >"$work/nginx.out" 2>&1 &
  nginx_pid=$!
  for _ in $(seq 1 100); do
    (exec 3<>"/dev/tcp/127.0.0.1/$nginx_grpc") 2>/dev/null && break
    sleep 0.1
  done
  echo "== nginx on 127.0.0.1:$nginx_grpc in front of $replicas replica(s)"
  "$loadtest" --server "127.0.0.1:$nginx_grpc" "${load[@]}" \
    --json "$out/scaleout_$name.json" --markdown "$out/scaleout_$name.md"
  # Which replica served how many calls (the access log names the upstream of every call).
  grep -o 'upstream=[^ ]*' "$work/access.log" | sort | uniq -c | sed 's/^ *//' | paste -sd ';' - \
    >"$work/routing_$name.txt"
  kill -TERM "$nginx_pid"; wait "$nginx_pid" 2>/dev/null || true; nginx_pid=""
  stop_servers
}
run_nginx 1 nginx1
run_nginx 3 nginx3

# ---- 3. nginx in front of 3 replicas on one redis-server (no shared directory)
run_redis() {  # run_redis NAME hash|rr
  local redis_port
  redis_port=$(free_port)
  rm -rf "$work/redis-$1"; mkdir -p "$work/redis-$1"
  "$redis" --bind 127.0.0.1 --port "$redis_port" --dir "$work/redis-$1" --save "" \
    --appendonly yes --appendfsync always --daemonize no >"$work/redis-$1.log" 2>&1 &
  redis_pid=$!
  for _ in $(seq 1 100); do
    (exec 3<>"/dev/tcp/127.0.0.1/$redis_port") 2>/dev/null && break
    sleep 0.1
  done
  run_nginx 3 "$1" "$2" --redis "redis://127.0.0.1:$redis_port"
  kill -TERM "$redis_pid"; wait "$redis_pid" 2>/dev/null || true; redis_pid=""
}
run_redis redis3_hash hash
run_redis redis3_rr rr
routing=$(cat "$work/routing_nginx3.txt")
routing_redis=$(cat "$work/routing_redis3_rr.txt")

# ---- the comparison
ROUTING="$routing" ROUTING_REDIS="$routing_redis" NGINX_VERSION="$("$nginx" -v 2>&1 | sed 's/.*\///')" \
REDIS_VERSION="$("$redis" --version | grep -o 'v=[0-9.]*' | cut -c3-)" python3 - "$out" <<'EOF'
import json, os, sys
out = sys.argv[1]
runs = {"single": "one server, direct", "nginx1": "nginx + 1 replica",
        "nginx3": "nginx + 3 replicas, shared state dir",
        "redis3_hash": "nginx (hash) + 3 replicas on Redis",
        "redis3_rr": "nginx (round robin) + 3 replicas on Redis"}
data = {k: json.load(open(f"{out}/scaleout_{k}.json")) for k in runs}
def row(d):
    m, w = d["moves"], d["watchers"]
    return {"moves_ok": m["ok"], "moves_failed": m["failed"],
            "moves_per_second": m["per_second_total"],
            "latency_ms": {q: m["latency_ms"][q] for q in ("p50", "p95", "p99", "max")},
            "server_solve_ms_p50": m["server_solve_ms"]["p50"],
            "watcher_delay_after_send_ms_p50": w["delay_after_send_ms"]["p50"],
            "watcher_end_status": w["end_status"],
            "setup_ms_p50": d["setup"]["setup_ms"]["p50"]}
rows = {k: row(d) for k, d in data.items()}
s = rows["single"]
def ratios(k):
    n = rows[k]
    return {"moves_per_second": n["moves_per_second"] / s["moves_per_second"],
            **{f"latency_{q}": n["latency_ms"][q] / s["latency_ms"][q] for q in ("p50", "p95", "p99")}}
machine = data["nginx3"]["machine"]
summary = {"tool": "bench/run_scaleout.sh", "config": data["single"]["config"],
           "machine": {"single": data["single"]["machine"], "nginx3": machine,
                       "nginx": os.environ["NGINX_VERSION"], "redis": os.environ["REDIS_VERSION"]},
           "runs": rows,
           "ratio_nginx3_over_single": ratios("nginx3"),
           "ratio_nginx1_over_single": ratios("nginx1"),
           "ratio_redis3_hash_over_single": ratios("redis3_hash"),
           "ratio_redis3_rr_over_single": ratios("redis3_rr"),
           "nginx_upstream_calls": os.environ["ROUTING"],
           "nginx_upstream_calls_redis3_rr": os.environ["ROUTING_REDIS"]}
summary["config"].pop("server", None)
json.dump(summary, open(f"{out}/scaleout.json", "w"), indent=2)
c = data["single"]["config"]
load = "; ".join(f"{k} {data[k]['machine']['load_average_start']} -> {data[k]['machine']['load_average_end']}"
                 for k in runs)
keys = list(runs)
lines = [
    f"# Scale-out: one server vs nginx + 1 / 3 replicas, on a shared directory or on Redis "
    f"({c['sessions']} sessions x {c['mesh']}, "
    f"{c['rate_hz']:g} Hz, {c['max_iterations']} iteration, {c['watchers_per_session']} watcher/session, "
    f"{c['duration_seconds']:g} s)", "",
    f"- date: {machine['date_utc']}; machine: nproc {machine['hardware_threads']}, CPU {machine['cpu_model']}",
    f"- load average (1/5/15 min) at start -> end of each run: {load}",
    f"- everything on this one machine over loopback: load tester, nginx {os.environ['NGINX_VERSION']} "
    "(docker/nginx.conf.template rendered for 127.0.0.1), the servers, redis-server "
    f"{os.environ['REDIS_VERSION']}; every revision is on disk before it is acknowledged (--state-dir "
    "fsyncs it; Redis runs appendonly yes, appendfsync always); default --workers and --refine-budget",
    "- nginx + 1 replica isolates the proxy's cost; with 3 replicas the replicas share the same "
    "cores (3 solver pools and 3 background refiners on 2 cores): this measures overhead, "
    "not added capacity (that needs replicas on separate hosts)",
    "- Redis runs: no shared directory; hash = the template's session affinity (a cache: any "
    "replica may serve any session); round robin = the template's hash lines taken out, so "
    "consecutive calls of one session land on different replicas, each catching up from Redis",
    f"- calls per upstream, 3 replicas on a shared directory (hash): {os.environ['ROUTING']}",
    f"- calls per upstream, 3 replicas on Redis, round robin: {os.environ['ROUTING_REDIS']}", "",
    "| | " + " | ".join(runs[k] for k in keys) + " | " +
    " | ".join(f"ratio {k} / direct" for k in keys[1:]) + " |",
    "|---|" + "---:|" * (2 * len(keys) - 1),
]
def cells(f):
    return " | ".join(f(rows[k]) for k in keys)
def ratio_cells(name, fmt):
    return " | ".join(fmt.format(ratios(k)[name]) for k in keys[1:])
blank = " | ".join("" for _ in keys[1:])
lines.append("| moves OK / failed | " + cells(lambda r: f"{r['moves_ok']} / {r['moves_failed']}") +
             " | " + blank + " |")
lines.append("| moves/s | " + cells(lambda r: f"{r['moves_per_second']:.2f}") + " | " +
             ratio_cells("moves_per_second", "{:.3f}") + " |")
for q in ("p50", "p95", "p99"):
    lines.append(f"| move latency {q} (ms) | " + cells(lambda r: f"{r['latency_ms'][q]:.1f}") +
                 " | " + ratio_cells("latency_" + q, "{:.2f}") + " |")
lines += [
    "| move latency max (ms) | " + cells(lambda r: f"{r['latency_ms']['max']:.1f}") + " | " + blank + " |",
    "| server solve p50 (ms) | " + cells(lambda r: f"{r['server_solve_ms_p50']:.1f}") + " | " + blank + " |",
    "| watcher receipt after send p50 (ms) | " +
    cells(lambda r: f"{r['watcher_delay_after_send_ms_p50']:.1f}") + " | " + blank + " |",
    "| setup (create + set handles) p50 (ms) | " + cells(lambda r: f"{r['setup_ms_p50']:.0f}") +
    " | " + blank + " |",
    "| watcher streams ended | " + cells(lambda r: str(r["watcher_end_status"])) + " | " + blank + " |",
    "", "Full reports: " + ", ".join(f"scaleout_{k}" for k in keys) + " (.md / .json).", ""]
open(f"{out}/scaleout.md", "w").write("\n".join(lines))
print("\n".join(lines))
EOF
echo "wrote $out/scaleout*.{md,json}"
