#!/usr/bin/env bash
# Issue 45: the service over emulated lines (the link emulator, linkemu; the load tester's
# --via-link), each run against a fresh meshdeform-server on loopback. Writes
# bench/results/link_*.{md,json}, each naming its link:
#  - link_spot187k_20mbit_meshopt: the 187k drag (Spot subdivided three times, 187,394 vertices,
#    as bench/run_multires_server.sh) at 10 Hz, one iteration per move, one watcher (the
#    editor's view), over 20 Mbit/s / 40 ms RTT, with the plain meshopt positions: the baseline;
#  - link_spot187k_20mbit_budget149k: the same drag with link-sized updates, quantized at the
#    default tolerance (1e-4 of the bounding-box diagonal) within 149,000 payload bytes per
#    update (the message around it adds ~60 bytes: at most 150,000 on the wire), the same
#    with --send-on-response (a missed tick's target sent as the response arrives), and the
#    same with --coarse-preview (the watcher also gets the coarse level of each move);
#  - link_spot187k_20mbit_budget149k_lossless_settled: that drag sending on response with the
#    adaptive window, its watcher asking for the settled revision exactly (--lossless-settled),
#    then up to 150 s after the drag for it (--settle-seconds): when the result after the
#    release arrives, and that it came lossless;
#  - link_spot47k_20mbit_quantized, link_cylinder_20mbit_{quantized,lossless}: the same drag of
#    Spot subdivided twice (46,850 vertices) and of the 4,802-vertex cylinder over the same
#    line, quantized without a budget (and the cylinder lossless): the cost at 5k and 50k;
#  - link_cylinder_16x10hz_loopback and link_cylinder_16x10hz_100mbit: 16 sessions of the
#    cylinder at 10 Hz, 2 watchers each, on loopback with the plain doubles (the same load
#    without a link, for the ratio on a noisy machine) and over 100 Mbit/s / 20 ms RTT (a line
#    per session) with quantized updates;
#  - codec: meshdeform-bench-codec on the three meshes (the codec alone on a smooth drag).
# Usage: bench/run_link.sh [BUILD_DIR] [SECONDS] (default ./build, 60). Needs python3.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
seconds="${2:-60}"
source bench/one_server.sh  # $server, $loadtest, $out; start_server / stop_server
for binary in "$build/cli/meshdeform-cli" "$build/bench/meshdeform-bench-codec"; do
  [[ -x "$binary" ]] || { echo "missing $binary: build with the CLI and the benches" >&2; exit 2; }
done
scratch=$(mktemp -d)
log="$scratch/server.log"
cleanup() { stop_server_if_running; rm -rf "$scratch"; }
trap cleanup EXIT

python3 - "$scratch/spot187k.obj" "$scratch/spot47k.obj" <<'PY'
import sys
V, F = [], []
for line in open("tests/data/spot.obj"):
    p = line.split()
    if p and p[0] == "v": V.append(tuple(float(x) for x in p[1:4]))
    elif p and p[0] == "f": F.append(tuple(int(x.split("/")[0]) - 1 for x in p[1:4]))
def write(path, V, F):
    with open(path, "w") as f:
        f.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in V))
        f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    print(f"spot: {len(V)} vertices, {len(F)} faces", file=sys.stderr)
for level in range(3):  # midpoint (1-to-4) subdivision
    if level == 2: write(sys.argv[2], V, F)
    mid, NV, NF = {}, list(V), []
    def m(a, b):
        k = (min(a, b), max(a, b))
        if k not in mid:
            mid[k] = len(NV)
            NV.append(tuple((V[a][i] + V[b][i]) / 2 for i in range(3)))
        return mid[k]
    for a, b, c in F:
        ab, bc, ca = m(a, b), m(b, c), m(c, a)
        NF += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
    V, F = NV, NF
write(sys.argv[1], V, F)
PY
"$build/cli/meshdeform-cli" generate --model cylinder --out-dir "$scratch" >/dev/null

window=(--fixed-receive-window)  # the receive window of every link case but the one below
drag() {  # NAME MESH|sample:NAME EXTRA_LOADTEST_FLAGS...
  local name=$1 source=(--mesh "$2")
  [[ $2 == sample:* ]] && source=(--sample "${2#sample:}")
  shift 2
  start_server --max-message-mib 256
  echo "== $name"
  "$loadtest" --server "127.0.0.1:$port" "${source[@]}" --sessions 1 --rate 10 \
    --iterations 1 --watchers 1 --duration "$seconds" --move-deadline-ms 60000 \
    --max-message-mib 256 --via-link 20mbit,40ms "${window[@]}" "$@" \
    --json "$out/$name.json" --markdown "$out/$name.md"
  stop_server
}
drag link_spot187k_20mbit_meshopt "$scratch/spot187k.obj" --encoding meshopt
drag link_spot187k_20mbit_budget149k "$scratch/spot187k.obj" --updates quantized \
  --max-update-bytes 149000
drag link_spot187k_20mbit_budget149k_send_on_response "$scratch/spot187k.obj" --updates quantized \
  --max-update-bytes 149000 --send-on-response
window=()
drag link_spot187k_20mbit_budget149k_send_on_response_adaptive_window "$scratch/spot187k.obj" \
  --updates quantized --max-update-bytes 149000 --send-on-response
drag link_spot187k_20mbit_budget149k_lossless_settled "$scratch/spot187k.obj" \
  --updates quantized --max-update-bytes 149000 --send-on-response --lossless-settled \
  --settle-seconds 150
window=(--fixed-receive-window)
drag link_spot187k_20mbit_budget149k_coarse_preview "$scratch/spot187k.obj" --updates quantized \
  --max-update-bytes 149000 --coarse-preview
drag link_spot47k_20mbit_quantized "$scratch/spot47k.obj" --updates quantized
drag link_cylinder_20mbit_quantized sample:cylinder --updates quantized
drag link_cylinder_20mbit_lossless sample:cylinder --updates lossless

start_server
echo "== link_cylinder_16x10hz_loopback"
"$loadtest" --server "127.0.0.1:$port" --sample cylinder --sessions 16 --rate 10 --iterations 1 \
  --watchers 2 --duration "$seconds" --json "$out/link_cylinder_16x10hz_loopback.json" \
  --markdown "$out/link_cylinder_16x10hz_loopback.md"
stop_server

start_server
echo "== link_cylinder_16x10hz_100mbit"
"$loadtest" --server "127.0.0.1:$port" --sample cylinder --sessions 16 --rate 10 --iterations 1 \
  --watchers 2 --duration "$seconds" --via-link 100mbit,20ms --fixed-receive-window \
  --updates quantized --json "$out/link_cylinder_16x10hz_100mbit.json" \
  --markdown "$out/link_cylinder_16x10hz_100mbit.md"
stop_server

echo "== codec"
"$build/bench/meshdeform-bench-codec" --mesh "$scratch/cylinder.off" --mesh "$scratch/spot47k.obj" \
  --mesh "$scratch/spot187k.obj" --markdown "$out/codec.md" --json "$out/codec.json"
