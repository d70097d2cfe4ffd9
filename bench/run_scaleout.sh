#!/usr/bin/env bash
# Scale-out benchmark of issue 6: the same load (meshdeform-loadtest, 8 sessions x cylinder
# (4,802 vertices) x 4 Hz x 1 outer iteration x 1 watcher) against
#   1. one meshdeform-server, directly (with --state-dir, so both runs persist every revision);
#   2. nginx (docker/nginx.conf.template rendered for loopback, as tests/scaleout does) in front
#      of 1 replica (the proxy's own cost) and of 3 replicas sharing one --state-dir,
# and writes bench/results/scaleout_{single,nginx1,nginx3}.{md,json} (the load tester's own reports) and
# the comparison bench/results/scaleout.{md,json}. Everything runs on 127.0.0.1.
# Usage: bench/run_scaleout.sh [BUILD_DIR] [DURATION_S] (defaults ./build, 30).
# Needs nginx (/usr/sbin/nginx, or $NGINX) and python3. Takes about 3 x DURATION_S + 15 s.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
duration="${2:-30}"
server="$build/server/transport/meshdeform-server"
loadtest="$build/client_cpp/loadtest/meshdeform-loadtest"
nginx="${NGINX:-/usr/sbin/nginx}"
out=bench/results
for binary in "$server" "$loadtest" "$nginx"; do
  [[ -x "$binary" ]] || { echo "missing $binary (build with ./scripts/build.sh; apt-get install nginx)" >&2; exit 2; }
done
mkdir -p "$out"
load=(--sessions 8 --sample cylinder --rate 4 --iterations 1 --watchers 1 --duration "$duration")

work=$(mktemp -d /tmp/meshdeform-scaleout-bench-XXXXXX)
chmod 0755 "$work"  # nginx's workers run unprivileged when this runs as root
pids=()
nginx_pid=""
cleanup() {
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
run_nginx() {  # run_nginx N NAME
  local replicas=$1 name=$2 grpc_servers="" http_servers="" i
  rm -rf "$work/state-shared" "$work/nginx-temp" "$work/access.log"
  for i in $(seq 1 "$replicas"); do
    start_server "replica$i" --state-dir "$work/state-shared"
    grpc_servers+="server 127.0.0.1:$port; "
    http_servers+="server 127.0.0.1:$http_port; "
  done
  nginx_grpc=$(free_port); nginx_http=$(free_port)
  mkdir -p "$work/nginx-temp"
  MESHDEFORM_GRPC_SERVERS="$grpc_servers" MESHDEFORM_HTTP_SERVERS="$http_servers" \
  NGINX_GRPC_LISTEN="127.0.0.1:$nginx_grpc" NGINX_HTTP_LISTEN="127.0.0.1:$nginx_http" \
  NGINX_TEMP_DIR="$work/nginx-temp" NGINX_ACCESS_LOG="$work/access.log" NGINX_ERROR_LOG="$work/error.log" \
  python3 - docker/nginx.conf.template "$work/nginx.conf" <<'PY'
import os, sys
names = ["MESHDEFORM_GRPC_SERVERS", "MESHDEFORM_HTTP_SERVERS", "NGINX_GRPC_LISTEN",
         "NGINX_HTTP_LISTEN", "NGINX_TEMP_DIR", "NGINX_ACCESS_LOG", "NGINX_ERROR_LOG"]
text = open(sys.argv[1]).read()
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
routing=$(cat "$work/routing_nginx3.txt")

# ---- the comparison
ROUTING="$routing" NGINX_VERSION="$("$nginx" -v 2>&1 | sed 's/.*\///')" python3 - "$out" <<'EOF'
import json, os, sys
out = sys.argv[1]
runs = {"single": "one server, direct", "nginx1": "nginx + 1 replica", "nginx3": "nginx + 3 replicas, shared state dir"}
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
s, p, n = rows["single"], rows["nginx1"], rows["nginx3"]
ratio = {"moves_per_second": n["moves_per_second"] / s["moves_per_second"],
         **{f"latency_{q}": n["latency_ms"][q] / s["latency_ms"][q] for q in ("p50", "p95", "p99")}}
machine = data["nginx3"]["machine"]
summary = {"tool": "bench/run_scaleout.sh", "config": data["single"]["config"],
           "machine": {"single": data["single"]["machine"], "nginx3": machine,
                       "nginx": os.environ["NGINX_VERSION"]},
           "runs": rows, "ratio_nginx3_over_single": ratio,
           "ratio_nginx1_over_single": {"moves_per_second": p["moves_per_second"] / s["moves_per_second"],
               **{f"latency_{q}": p["latency_ms"][q] / s["latency_ms"][q] for q in ("p50", "p95", "p99")}},
           "nginx_upstream_calls": os.environ["ROUTING"]}
summary["config"].pop("server", None)
json.dump(summary, open(f"{out}/scaleout.json", "w"), indent=2)
c = data["single"]["config"]
r1 = summary["ratio_nginx1_over_single"]
load = "; ".join(f"{k} {data[k]['machine']['load_average_start']} -> {data[k]['machine']['load_average_end']}"
                 for k in runs)
lines = [
    f"# Scale-out: one server vs nginx + 1 / 3 replicas ({c['sessions']} sessions x {c['mesh']}, "
    f"{c['rate_hz']:g} Hz, {c['max_iterations']} iteration, {c['watchers_per_session']} watcher/session, "
    f"{c['duration_seconds']:g} s)", "",
    f"- date: {machine['date_utc']}; machine: nproc {machine['hardware_threads']}, CPU {machine['cpu_model']}",
    f"- load average (1/5/15 min) at start -> end of each run: {load}",
    f"- everything on this one machine over loopback: load tester, nginx {os.environ['NGINX_VERSION']} "
    "(docker/nginx.conf.template rendered for 127.0.0.1), the servers; every run with --state-dir "
    "(every revision fsync'ed before it is acknowledged), default --workers and --refine-budget",
    "- nginx + 1 replica isolates the proxy's cost; with 3 replicas the replicas share the same "
    "cores (3 solver pools and 3 background refiners on 2 cores): this measures overhead, "
    "not added capacity (that needs replicas on separate hosts)",
    f"- calls per upstream in the 3-replica run (nginx access log): {os.environ['ROUTING']}", "",
    "| | one server, direct | nginx + 1 replica | nginx + 3 replicas | ratio 1 replica / direct | ratio 3 replicas / direct |",
    "|---|---:|---:|---:|---:|---:|",
    f"| moves OK / failed | {s['moves_ok']} / {s['moves_failed']} | {p['moves_ok']} / {p['moves_failed']} | "
    f"{n['moves_ok']} / {n['moves_failed']} | | |",
    f"| moves/s | {s['moves_per_second']:.2f} | {p['moves_per_second']:.2f} | {n['moves_per_second']:.2f} | "
    f"{r1['moves_per_second']:.3f} | {ratio['moves_per_second']:.3f} |",
]
for q in ("p50", "p95", "p99"):
    lines.append(f"| move latency {q} (ms) | {s['latency_ms'][q]:.1f} | {p['latency_ms'][q]:.1f} | "
                 f"{n['latency_ms'][q]:.1f} | {r1['latency_' + q]:.2f} | {ratio['latency_' + q]:.2f} |")
lines += [
    f"| move latency max (ms) | {s['latency_ms']['max']:.1f} | {p['latency_ms']['max']:.1f} | {n['latency_ms']['max']:.1f} | | |",
    f"| server solve p50 (ms) | {s['server_solve_ms_p50']:.1f} | {p['server_solve_ms_p50']:.1f} | {n['server_solve_ms_p50']:.1f} | | |",
    f"| watcher receipt after send p50 (ms) | {s['watcher_delay_after_send_ms_p50']:.1f} | "
    f"{p['watcher_delay_after_send_ms_p50']:.1f} | {n['watcher_delay_after_send_ms_p50']:.1f} | | |",
    f"| setup (create + set handles) p50 (ms) | {s['setup_ms_p50']:.0f} | {p['setup_ms_p50']:.0f} | {n['setup_ms_p50']:.0f} | | |",
    f"| watcher streams ended | {s['watcher_end_status']} | {p['watcher_end_status']} | {n['watcher_end_status']} | | |",
    "", "Full reports: scaleout_single, scaleout_nginx1, scaleout_nginx3 (.md / .json).", ""]
open(f"{out}/scaleout.md", "w").write("\n".join(lines))
print("\n".join(lines))
EOF
echo "wrote $out/scaleout*.{md,json}"
