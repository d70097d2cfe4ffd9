#!/usr/bin/env bash
# Issue 15 through the server: one interactive session on Spot subdivided to 187,394 vertices
# (three midpoint subdivisions of tests/data/spot.obj, written to a scratch directory), dragged
# by the load tester at 10 Hz with one outer iteration per move and one watcher, with the
# multiresolution path (the default --multires-above 100000) and without it (--multires-above 0),
# each against a fresh server on loopback. Writes bench/results/multires_server_{multires,single}
# .{md,json} (with ENCODING float32 or meshopt: ..._{multires,single}_ENCODING.{md,json}, moves and
# watch updates carrying compact positions). Usage:
# bench/run_multires_server.sh [BUILD_DIR] [SECONDS] [ENCODING] (default ./build, 90, doubles).
# Needs python3 (to subdivide). Run it on a quiet machine: the figures are latencies.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
seconds="${2:-90}"
encoding="${3:-doubles}"
suffix=""
[[ $encoding != doubles ]] && suffix="_$encoding"
source bench/one_server.sh  # $server, $loadtest, $out; start_server / stop_server
scratch=$(mktemp -d)
log="$scratch/server.log"
cleanup() { stop_server_if_running; rm -rf "$scratch"; }
trap cleanup EXIT

python3 - "$scratch/spot187k.obj" <<'PY'
import sys
V, F = [], []
for line in open("tests/data/spot.obj"):
    p = line.split()
    if p and p[0] == "v": V.append(tuple(float(x) for x in p[1:4]))
    elif p and p[0] == "f": F.append(tuple(int(x.split("/")[0]) - 1 for x in p[1:4]))
for _ in range(3):  # midpoint (1-to-4) subdivision
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
with open(sys.argv[1], "w") as f:
    f.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in V))
    f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
print(f"spot: {len(V)} vertices, {len(F)} faces", file=sys.stderr)
PY


for variant in multires single; do
  flags=()
  [[ $variant == single ]] && flags=(--multires-above 0)
  start_server --max-message-mib 256 "${flags[@]}"
  echo "== $variant"
  "$loadtest" --server "127.0.0.1:$port" --mesh "$scratch/spot187k.obj" --sessions 1 --rate 10 \
    --iterations 1 --watchers 1 --duration "$seconds" --move-deadline-ms 60000 \
    --max-message-mib 256 --encoding "$encoding" --json "$out/multires_server_$variant$suffix.json" \
    --markdown "$out/multires_server_$variant$suffix.md"
  stop_server
done
echo "wrote $out/multires_server_{multires,single}$suffix.{md,json}"
