#!/usr/bin/env bash
# The container check (issue 42): builds the meshdeform-server image from docker/Dockerfile with
# podman, runs it as shipped, then runs docker/compose.yaml's topology and fails a replica under
# load. Too slow for every CI run (the image build compiles the server): run it before changing
# anything under docker/ or the server's library dependencies, and record its result in
# docker/README.md ("Last run").
#
#   scripts/container-check.sh [--fresh | --skip-build] [--keep-logs]
#     --fresh       build every stage again (podman build --no-cache): the run to record
#     --skip-build  use the image built last (localhost/meshdeform-server:local) as it is
#     --keep-logs   keep the logs (in /var/tmp/meshdeform-container-check.*) after a pass too
#
# What it checks, in order (each wait bounded; the first failure stops it with "FAIL: ..."):
#  1. the base images exist (docker/make-base-images.sh: debootstrap, no registry) and the image
#     builds (`podman build`, nice -n 5, MESHDEFORM_CHECK_JOBS compile jobs, default every core);
#  2. the image: runs as meshdeform (uid 10001), carries the HEALTHCHECK, and every library of the
#     server resolves inside it (ldd: nothing "not found");
#  3. the image as shipped (its ENTRYPOINT, a named volume on /var/lib/meshdeform): answers
#     /healthz, its health check passes, the server process runs as uid 10001, a session is created
#     and moved, its state file in the volume belongs to uid 10001, and after `podman stop`
#     (SIGTERM, clean exit) a new container on the same volume serves the session at the same
#     revision with the same positions;
#  4. compose.yaml's topology, started with podman-compose (Redis, three replicas, nginx; the
#     ports published on 127.0.0.1 at free ports; every replica healthy, running as uid 10001 and
#     resolving the service name redis): meshdeform-loadtest (built on the host) drags 4
#     sessions through nginx at 10 Hz for 120 s; a meshdeform-client drag (converged moves: no
#     background refinement revisions in between) runs on a session of its own that lands on a
#     replica serving load-test sessions too; that replica's server process is killed with SIGKILL
#     (a crash: its restart policy may bring it back) while the load tester's sessions on it are
#     mid-drag. Then, through nginx: the drag's session is at exactly its last acknowledged revision
#     with byte-identical positions and the drag goes on from it (consecutive revisions), every
#     load-test session of the victim moves again (printed: how long after the kill each one's
#     first move was acknowledged, from nginx's log), at least 30 s of the load's move phase follow
#     the kill (printed: how long it ran), and the load tester ends with every session set up
#     and closed, every failed move UNAVAILABLE/ABORTED/DEADLINE_EXCEEDED/INTERNAL, and per session
#     last_revision = moves_ok + revision_gaps (a consistency check: a revision lost in the
#     failover would have its number handed out again; background refinement revisions between
#     moves could hide that, which is why the drag's session is the exact check).
# Everything it starts (containers and their anonymous volumes, the compose project's network and
# volumes, the load tester) is removed on exit, pass or fail (trap); on failure the logs stay
# (every container's too). The images stay (base images, stand-ins, the built image).
#
# Needs root (podman rootful, debootstrap) and the host's build of the client tools:
#   cmake --build build --target meshdeform-loadtest meshdeform-client
# MESHDEFORM_BUILD_DIR names another build directory. Network: Debian's mirror and npm's registry
# for the image build; everything else stays on this machine (containers on a podman bridge
# network of their own, published on 127.0.0.1).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${MESHDEFORM_BUILD_DIR:-$root/build}"
jobs="${MESHDEFORM_CHECK_JOBS:-$(nproc)}"
image=localhost/meshdeform-server:local
skip_build=0
keep_logs=0
cache=()
for arg in "$@"; do
  case "$arg" in
    --fresh) cache=(--no-cache) ;;
    --skip-build) skip_build=1 ;;
    --keep-logs) keep_logs=1 ;;
    *) sed -n '8,11p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2 ;;
  esac
done

start=$SECONDS
step() { echo "== container-check: $* ($((SECONDS - start))s)"; }
note() { echo "   $*"; }
fail() {
  echo "container-check: FAIL: $*" >&2
  exit 1
}

[ "$(id -u)" -eq 0 ] || { echo "container-check: run as root (rootful podman, debootstrap)" >&2; exit 2; }
loadtest="$build/client_cpp/loadtest/meshdeform-loadtest"
client="$build/client_cpp/meshdeform-client"
for tool in "$loadtest" "$client"; do
  [ -x "$tool" ] || {
    echo "container-check: $tool is missing: cmake --build build --target meshdeform-loadtest meshdeform-client" >&2
    exit 2
  }
done
# podman and what it runs with (Debian 12), debootstrap for the base images, curl and jq here.
"$root/scripts/install-deps.sh" podman podman-compose runc crun conmon netavark aardvark-dns \
  containernetworking-plugins slirp4netns fuse-overlayfs uidmap iptables debootstrap curl jq

project="mdcheck$$"
scratch="$(mktemp -d /var/tmp/meshdeform-container-check.XXXXXX)"
compose_started=0
single=""
single_volume=""
loadtest_pid=""
cleanup() {
  local status=$?
  set +e
  [ -n "$loadtest_pid" ] && kill "$loadtest_pid" 2>/dev/null && wait "$loadtest_pid" 2>/dev/null
  if [ "$compose_started" -eq 1 ]; then
    # On failure, each container's log (nginx's is the access log) stays with the other logs.
    if [ "$status" -ne 0 ] || [ "$keep_logs" -eq 1 ]; then
      for c in $(podman ps -a --format '{{.Names}}' --filter "label=io.podman.compose.project=$project"); do
        podman logs "$c" >"$scratch/container-$c.log" 2>&1
      done
    fi
    # The project's containers with their anonymous volumes first (the image's VOLUME gives each
    # replica one; podman-compose 1.0's `down -v` removes only the named ones), then the rest.
    podman ps -a -q --filter "label=io.podman.compose.project=$project" |
      xargs -r podman rm -f -v -t 5 >"$scratch/compose-rm.log" 2>&1
    compose down -v -t 5 >"$scratch/compose-down.log" 2>&1
    # podman-compose 1.0 leaves the project's network behind.
    podman network rm -f "${project}_default" >/dev/null 2>&1
  fi
  [ -n "$single" ] && podman rm -f -t 5 "$single" >/dev/null 2>&1
  [ -n "$single_volume" ] && podman volume rm -f "$single_volume" >/dev/null 2>&1
  if [ "$status" -ne 0 ] || [ "$keep_logs" -eq 1 ]; then
    echo "container-check: logs kept in $scratch" >&2
  else
    rm -rf "$scratch"
  fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# ---- podman on this machine --------------------------------------------------------------------
# Two of podman's defaults fail in these VMs; a containers.conf of the check's own fixes both
# (unless CONTAINERS_CONF already names one):
#  - the default OCI runtime crun refuses the hybrid cgroup layout (v1 controllers plus a cgroup2
#    mount at /sys/fs/cgroup/unified): "cgroups in hybrid mode not supported"; runc runs there;
#  - podman asks for RLIMIT_NOFILE 1048576 in every container, above this machine's hard limit,
#    and without CAP_SYS_RESOURCE the runtime cannot raise it ("setrlimit `RLIMIT_NOFILE`:
#    Operation not permitted"): the containers get the machine's hard limits instead.
if [ -z "${CONTAINERS_CONF:-}" ]; then
  nofile="$(ulimit -Hn)"
  nproc="$(ulimit -Hu)"
  if [ "$nproc" = "unlimited" ] || [ "$nproc" -gt 32768 ]; then nproc=32768; fi  # podman's default
  if [ "$nofile" = "unlimited" ]; then nofile=1048576; fi
  runtime=crun
  if awk '$9 == "cgroup2" && $5 == "/sys/fs/cgroup/unified" {found=1} END {exit !found}' /proc/self/mountinfo; then
    runtime=runc
  fi
  cat >"$scratch/containers.conf" <<EOF
[containers]
default_ulimits = ["nofile=$nofile:$nofile", "nproc=$nproc:$nproc"]
[engine]
runtime = "$runtime"
EOF
  export CONTAINERS_CONF="$scratch/containers.conf"
  note "podman: runtime $runtime, ulimits nofile=$nofile nproc=$nproc ($CONTAINERS_CONF)"
fi

# ---- 1. base images and the image --------------------------------------------------------------
step "1. base images (docker/make-base-images.sh) and the image"
"$root/docker/make-base-images.sh"
if [ "$skip_build" -eq 0 ]; then
  build_start=$SECONDS
  # npm inside the build trusts this machine's CA bundle too (the build secret ca_bundle): the
  # way out of these machines re-signs TLS with a CA of its own.
  secret=()
  [ -s /etc/ssl/certs/ca-certificates.crt ] &&
    secret=(--secret id=ca_bundle,src=/etc/ssl/certs/ca-certificates.crt)
  if ! nice -n 5 podman build --pull=never --format docker "${cache[@]}" "${secret[@]}" \
      --ignorefile "$root/docker/Dockerfile.dockerignore" --build-arg BUILD_JOBS="$jobs" \
      -f "$root/docker/Dockerfile" -t "$image" "$root" >"$scratch/build.log" 2>&1; then
    tail -40 "$scratch/build.log" >&2
    fail "podman build failed (log: $scratch/build.log)"
  fi
  note "built $image in $((SECONDS - build_start)) s with $jobs compile jobs${cache:+, every stage anew (--no-cache)}"
fi
podman image exists "$image" || fail "$image does not exist (run without --skip-build)"
note "image: $(podman image inspect --format '{{.Id}}' "$image" | cut -c1-12)," \
  "$(podman image inspect --format '{{.Size}}' "$image" | awk '{printf "%.0f MB", $1 / 1e6}')"

# ---- 2. the image's own facts ------------------------------------------------------------------
step "2. user, health check and libraries of the image"
user="$(podman image inspect --format '{{.Config.User}}' "$image")"
[ "$user" = "meshdeform:meshdeform" ] || fail "the image's user is '$user', not meshdeform:meshdeform"
health="$(podman image inspect --format '{{.Config.Healthcheck}}' "$image")"
case "$health" in *healthz*) ;; *) fail "the image carries no /healthz HEALTHCHECK ($health)" ;; esac
podman run --rm --pull=never --entrypoint ldd "$image" /usr/local/bin/meshdeform-server \
  >"$scratch/ldd.txt" 2>&1 || fail "ldd in the image failed: $(cat "$scratch/ldd.txt")"
if grep -q 'not found' "$scratch/ldd.txt"; then
  fail "libraries missing in the image: $(grep 'not found' "$scratch/ldd.txt" | tr '\n' ' ')"
fi
note "user $user; $(grep -c '=> /' "$scratch/ldd.txt") libraries and the loader resolve in the image, none missing"

free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}
# Waits (at most $2 seconds) until command "$@" (from $3 on) succeeds.
wait_for() {
  local what="$1" limit="$2"
  shift 2
  local deadline=$((SECONDS + limit))
  until "$@" >/dev/null 2>&1; do
    [ $SECONDS -lt "$deadline" ] || return 1
    sleep 0.5
  done
  note "$what after $((SECONDS - deadline + limit)) s"
}
json_field() { jq -r ".$1" "$2"; }
# cli ADDRESS ARGS...: the client with a bounded deadline per call.
cli() {
  local address="$1"
  shift
  "$client" --server "$address" --timeout 60 "$@"
}
translation_def() {  # a .def moving the handles by (0, 0, $1)
  printf '1 0 0 0\n0 1 0 0\n0 0 1 %s\n0 0 0 1\n' "$1" >"$2"
}

# ---- 3. the image as shipped -------------------------------------------------------------------
step "3. the image as shipped: its entrypoint, the state volume, the non-root user"
grpc_port="$(free_port)"
http_port="$(free_port)"
single="${project}-single"
single_volume="${project}-state"
podman volume create "$single_volume" >/dev/null
# podman without systemd cannot schedule the periodic health check ("unable to get systemd
# connection to add healthchecks", logged, harmless): `podman healthcheck run` runs it on demand.
run_single() {
  podman run -d --pull=never --name "$single" -v "$single_volume:/var/lib/meshdeform" \
    -p "127.0.0.1:$grpc_port:50051" -p "127.0.0.1:$http_port:8080" "$image" >/dev/null 2>>"$scratch/podman.log"
}
run_single
wait_for "/healthz answered" 90 curl -fsS "http://127.0.0.1:$http_port/healthz" ||
  fail "the server in $image never answered /healthz: $(podman logs --tail 20 "$single" 2>&1)"
podman healthcheck run "$single" >/dev/null || fail "the image's HEALTHCHECK fails"
# (Into a file first: with pipefail, grep -q leaving early could fail curl's write.)
curl -fsS -o "$scratch/index.html" "http://127.0.0.1:$http_port/" && grep -qi '<html' "$scratch/index.html" ||
  fail "the viewer is not served at /"
uid="$(podman exec "$single" sh -c 'awk "/^Uid:/ {print \$2}" /proc/1/status')"
[ "$uid" = "10001" ] || fail "the server runs as uid $uid, not 10001"
[ "$(podman exec "$single" id -un)" = "meshdeform" ] || fail "exec in the container is not user meshdeform"
cli "127.0.0.1:$grpc_port" create --sample cylinder_small >"$scratch/single-create.json" ||
  fail "create through the published port failed"
sid="$(json_field session_id "$scratch/single-create.json")"
token="$(json_field edit_token "$scratch/single-create.json")"
jq '.suggested_groups' "$scratch/single-create.json" >"$scratch/groups.json"
cli "127.0.0.1:$grpc_port" handles --session "$sid" --token "$token" --groups "$scratch/groups.json" \
  >/dev/null || fail "handles failed"
translation_def 0.2 "$scratch/single.def"
cli "127.0.0.1:$grpc_port" move --session "$sid" --token "$token" --def "$scratch/single.def" \
  --iterations 300 --tolerance 1e-9 >"$scratch/single-move.json" || fail "move failed"
revision="$(json_field revision "$scratch/single-move.json")"
cli "127.0.0.1:$grpc_port" get --session "$sid" --token "$token" --out "$scratch/single-before.obj" \
  >/dev/null || fail "get failed"
owners="$(podman exec "$single" sh -c 'stat -c %u /var/lib/meshdeform/* | sort -u | tr "\n" " "')"
[ "$owners" = "10001 " ] || fail "files in the state volume belong to uids '$owners', not 10001"
files="$(podman exec "$single" sh -c 'ls /var/lib/meshdeform | wc -l')"
podman stop -t 20 "$single" >/dev/null 2>>"$scratch/podman.log"
exit_code="$(podman inspect --format '{{.State.ExitCode}}' "$single")"
[ "$exit_code" = "0" ] || fail "the server exited $exit_code on SIGTERM: $(podman logs --tail 20 "$single" 2>&1)"
podman rm "$single" >/dev/null 2>>"$scratch/podman.log"
run_single
wait_for "a new container on the same volume answered /healthz" 90 \
  curl -fsS "http://127.0.0.1:$http_port/healthz" || fail "the second container never became healthy"
cli "127.0.0.1:$grpc_port" info --session "$sid" --token "$token" >"$scratch/single-info.json" ||
  fail "the session did not survive the container (info failed)"
[ "$(json_field revision "$scratch/single-info.json")" = "$revision" ] ||
  fail "revision $(json_field revision "$scratch/single-info.json") after the restart, $revision before"
cli "127.0.0.1:$grpc_port" get --session "$sid" --token "$token" --out "$scratch/single-after.obj" \
  >/dev/null || fail "get after the restart failed"
cmp -s "$scratch/single-before.obj" "$scratch/single-after.obj" ||
  fail "the positions changed across the container restart"
note "server uid 10001; session $sid: revision $revision, $files state file(s) of uid 10001 in the volume;"
note "SIGTERM exit 0; a new container on the volume serves revision $revision, identical positions"
podman rm -f -t 5 "$single" >/dev/null 2>>"$scratch/podman.log"
podman volume rm -f "$single_volume" >/dev/null
single=""
single_volume=""

# ---- 4. the compose topology, a replica killed mid-drag ----------------------------------------
step "4. compose.yaml: Redis, three replicas, nginx; a replica killed mid-drag"
export MESHDEFORM_PUBLISH_ADDRESS=127.0.0.1
MESHDEFORM_GRPC_PORT="$(free_port)"
MESHDEFORM_HTTP_PORT="$(free_port)"
export MESHDEFORM_GRPC_PORT MESHDEFORM_HTTP_PORT
nginx_grpc="127.0.0.1:$MESHDEFORM_GRPC_PORT"
compose() { podman-compose -p "$project" -f "$root/docker/compose.yaml" "$@"; }
container_of() { echo "${project}_$1_1"; }  # podman-compose 1.0's naming
compose_started=1
# Redis first and healthy (podman-compose 1.0 orders by depends_on but ignores its conditions;
# a replica that finds no Redis exits 2 and its restart policy brings it back).
compose up -d --no-build redis >"$scratch/compose-up.log" 2>&1 || fail "compose up redis failed"
wait_for "Redis answered PING" 60 podman exec "$(container_of redis)" redis-cli ping ||
  fail "Redis never answered"
compose up -d --no-build >>"$scratch/compose-up.log" 2>&1 || {
  tail -20 "$scratch/compose-up.log" >&2
  fail "compose up failed"
}
replicas=(meshdeform-1 meshdeform-2 meshdeform-3)
for r in "${replicas[@]}"; do
  wait_for "$r healthy" 90 podman healthcheck run "$(container_of "$r")" ||
    fail "$r never became healthy: $(podman logs --tail 20 "$(container_of "$r")" 2>&1)"
done
wait_for "nginx answered /healthz" 60 curl -fsS "http://127.0.0.1:$MESHDEFORM_HTTP_PORT/healthz" ||
  fail "nginx never answered: $(podman logs --tail 20 "$(container_of nginx)" 2>&1)"
for r in "${replicas[@]}"; do
  uid="$(podman exec "$(container_of "$r")" sh -c 'awk "/^Uid:/ {print \$2}" /proc/1/status')"
  [ "$uid" = "10001" ] || fail "$r runs as uid $uid"
done
# The replicas open more Redis connections under load, each resolving the service name `redis`
# (aardvark-dns, podman's resolver for the project's network). Each resolves it promptly before
# the load starts, three times in a row: a resolver that does not answer would otherwise show up
# only as sessions failing setup after some 40 s (the glibc resolver's timeouts, then the
# host's resolver's NXDOMAIN: "redis at redis:6379 is unreachable: No address associated with
# hostname").
resolves_redis() {
  local i
  for i in 1 2 3; do timeout 3 podman exec "$1" getent ahostsv4 redis >/dev/null 2>&1 || return 1; done
}
for r in "${replicas[@]}"; do
  wait_for "$r resolved redis" 60 resolves_redis "$(container_of "$r")" ||
    fail "$r cannot resolve the service name redis (aardvark-dns)"
done

declare -A replica_of_ip=()
# nginx's access log: one line per call, with the session id and the upstream(s) it went to.
nginx_log() { podman logs "$(container_of nginx)" 2>/dev/null; }
# The replica that answered a line's call: the last address of its upstream field ("a:50051,
# b:50051" when nginx moved on to a second replica).
replica_of_line() {
  local ip
  ip="$(sed -n 's/.* upstream=\(.*\) upstream_status=.*/\1/p' | awk -F', ' '{print $NF}' | cut -d: -f1)"
  echo "${replica_of_ip[$ip]:-}"
}
for r in "${replicas[@]}"; do
  ip="$(podman inspect --format '{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}' "$(container_of "$r")")"
  replica_of_ip["$ip"]="$r"
done
replica_of_session() { nginx_log | grep "sid=\"$sid\"" | tail -1 | replica_of_line; }

# The load: the load tester through nginx, 4 sessions dragged at 10 Hz each for 120 s. The kill
# comes once the sessions are moving and the client's drag has made 6 converged moves (seconds
# into the load on a quiet machine, up to a minute on a busy one; more than 90 s fails); the
# check fails unless at least 30 s of the load's move phase follow the kill.
loadtest_start=$SECONDS
"$loadtest" --server "$nginx_grpc" --sessions 4 --rate 10 --duration 120 --move-deadline-ms 20000 \
  --json "$scratch/loadtest.json" --markdown "$scratch/loadtest.md" >"$scratch/loadtest.out" 2>&1 &
loadtest_pid=$!
wait_for "the load tester's sessions moving" 60 \
  sh -c "podman logs $(container_of nginx) 2>/dev/null | grep -c MoveHandles | awk '{exit \$1 < 40}'" ||
  fail "the load tester never got moving: $(tail -5 "$scratch/loadtest.out")"
declare -A loaded=()  # replicas serving load-test sessions
while read -r line; do
  r="$(replica_of_line <<<"$line")"
  [ -n "$r" ] && loaded["$r"]=1
done < <(nginx_log | grep MoveHandles)
[ ${#loaded[@]} -gt 0 ] || fail "nginx's log names no replica for the load tester's moves"

# The drag of the client: its own session, converged moves (no background refinement revisions),
# on a replica that serves load-test sessions too (a session lands where its id hashes: create
# sessions until one does, at most 12).
for ((try = 1; try <= 12; try++)); do
  cli "$nginx_grpc" create --sample cylinder_small >"$scratch/drag-create.json" ||
    fail "create through nginx failed"
  sid="$(json_field session_id "$scratch/drag-create.json")"
  token="$(json_field edit_token "$scratch/drag-create.json")"
  jq '.suggested_groups' "$scratch/drag-create.json" >"$scratch/groups.json"
  cli "$nginx_grpc" handles --session "$sid" --token "$token" --groups "$scratch/groups.json" \
    >/dev/null || fail "handles through nginx failed"
  victim="$(replica_of_session)"
  [ -n "${loaded[$victim]:-}" ] && break
  cli "$nginx_grpc" close --session "$sid" --token "$token" >/dev/null || true
  victim=""
done
[ -n "$victim" ] || fail "no session of 12 landed on a replica serving the load tester (${!loaded[*]})"
acked=()  # acknowledged revisions of the drag, in order
# drag_move STEP [ATTEMPTS]: one converged move; retries (1 s apart) while the session moves to a
# surviving replica. Records the acknowledged revision and saves the mesh at it.
drag_move() {
  local step="$1" attempts="${2:-1}" attempt out="$scratch/drag-move-$1.json" err="$scratch/drag-move-$1.err"
  translation_def "$(awk -v s="$step" 'BEGIN {print s / 40}')" "$scratch/drag.def"
  for ((attempt = 1; attempt <= attempts; attempt++)); do
    if cli "$nginx_grpc" move --session "$sid" --token "$token" --def "$scratch/drag.def" \
        --iterations 300 --tolerance 1e-9 >"$out" 2>"$err"; then
      local revision
      revision="$(json_field revision "$out")"
      acked+=("$revision")
      cli "$nginx_grpc" get --session "$sid" --token "$token" --revision "$revision" \
        --out "$scratch/drag-rev-$revision.obj" >/dev/null || fail "get of acknowledged revision $revision failed"
      return 0
    fi
    sleep 1
  done
  fail "move $step of the drag failed $attempts times: $(cat "$err")"
}
for s in 1 2 3 4 5 6; do drag_move "$s"; done
[ "$(replica_of_session)" = "$victim" ] || fail "the drag's session moved off $victim before the kill"
last_before="${acked[-1]}"
# The load tester's sessions on the victim, and their moves it served so far.
victim_ip="$(podman inspect --format '{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}' "$(container_of "$victim")")"
nginx_log | grep MoveHandles | grep -v "sid=\"$sid\"" | grep "upstream=$victim_ip:" \
  >"$scratch/victim-moves.log" || true
victim_sessions="$(sed -n 's/.*sid="\([0-9a-f]*\)".*/\1/p' "$scratch/victim-moves.log" | sort -u | wc -l)"
# A crash, not a stop: SIGKILL to the replica's server process (the container's main process,
# by its pid on this host), so that the replica's restart policy sees a crash.
victim_pid="$(podman inspect --format '{{.State.Pid}}' "$(container_of "$victim")")"
[ "$victim_pid" -gt 1 ] || fail "no pid for $victim"
kill -KILL "$victim_pid"
kill_time="$(date +%s.%N)"
kill_epoch="${kill_time%.*}"
kill_at=$((SECONDS - loadtest_start))
[ "$kill_at" -le 90 ] || fail "the kill came $kill_at s into the 120 s load test: too late to see the failover under load"
note "killed $victim (SIGKILL to pid $victim_pid) $kill_at s into the load test, after drag revision $last_before;" \
  "it served $victim_sessions load-test session(s) mid-drag ($(wc -l <"$scratch/victim-moves.log") of their moves so far)"

# Through nginx, the session resumes on a survivor at exactly the last acknowledged revision.
wait_for "the session answered through a survivor" 60 \
  cli "$nginx_grpc" info --session "$sid" --token "$token" || fail "the session never came back"
cli "$nginx_grpc" info --session "$sid" --token "$token" >"$scratch/drag-info.json"
now="$(json_field revision "$scratch/drag-info.json")"
[ "$now" = "$last_before" ] ||
  fail "after the kill the session is at revision $now, the last acknowledged was $last_before"
cli "$nginx_grpc" get --session "$sid" --token "$token" --out "$scratch/drag-after-kill.obj" >/dev/null ||
  fail "get after the kill failed"
cmp -s "$scratch/drag-rev-$last_before.obj" "$scratch/drag-after-kill.obj" ||
  fail "the positions of revision $last_before changed in the failover"
for s in 7 8 9 10 11 12; do drag_move "$s" 30; done
# Served by a survivor, or by the killed replica again once its restart policy brought it back
# (it then loaded the session from Redis like any other replica): both must keep the revision.
survivor="$(replica_of_session)"
[ -n "$survivor" ] || fail "nginx's log does not say which replica served the drag after the kill"
restarts="$(podman inspect --format '{{.RestartCount}}' "$(container_of "$victim")" 2>/dev/null || echo '?')"
[ "$victim_sessions" -gt 0 ] || fail "no load-test session was on $victim when it was killed"
for ((i = 1; i < ${#acked[@]}; i++)); do
  [ "${acked[$i]}" -eq $((acked[i - 1] + 1)) ] ||
    fail "the drag's acknowledged revisions are not consecutive: ${acked[*]}"
done
note "drag on session $sid: revisions ${acked[*]}; after the kill the session was at $now with"
note "identical positions, and went on at $survivor ($victim restarted $restarts time(s) by its policy)"

# The load tester ends by itself when its 120 s are up (bounded wait: 240 s from here).
deadline=$((SECONDS + 240))
while kill -0 "$loadtest_pid" 2>/dev/null; do
  [ $SECONDS -lt $deadline ] || fail "the load tester is still running 240 s after the drag's end"
  sleep 1
done
loadtest_status=0
wait "$loadtest_pid" || loadtest_status=$?
loadtest_pid=""
[ -f "$scratch/loadtest.json" ] || fail "the load tester wrote no report (exit $loadtest_status): $(tail -5 "$scratch/loadtest.out")"
report="$scratch/loadtest.json"
[ "$(jq -r .completed "$report")" = "true" ] || fail "the load test did not complete"
bad="$(jq -r '[.sessions[] | select(.set_up != true or .close_status != "OK")] | length' "$report")"
[ "$bad" = "0" ] || fail "$bad load-test sessions not set up or not closed OK: $(jq -c '[.sessions[] | {index, setup_status, setup_error, close_status}]' "$report")"
codes="$(jq -r '[.sessions[].errors_by_code | keys[]] | unique | join(" ")' "$report")"
for code in $codes; do
  case "$code" in
    UNAVAILABLE | ABORTED | DEADLINE_EXCEEDED | INTERNAL) ;;
    *) fail "load-test moves failed with $code: $(jq -c '[.sessions[].errors_by_code]' "$report")" ;;
  esac
done
short="$(jq -r '[.sessions[] | select(.last_revision != .moves_ok + .revision_gaps)] | length' "$report")"
[ "$short" = "0" ] || fail "load-test sessions whose revisions do not add up (lost revisions?): $(jq -c '[.sessions[] | {index, last_revision, moves_ok, revision_gaps}]' "$report")"
# How long the load ran after the kill: the end of the load tester's move phase (its start time,
# whole seconds, plus its setup and move phases) minus the time of the kill.
phase_end="$(jq -r '(.machine.date_utc | fromdateiso8601) + .phases.setup_seconds + .phases.move_seconds | floor' "$report")"
load_after_kill=$((phase_end - kill_epoch))
[ "$load_after_kill" -ge 30 ] ||
  fail "the load's move phase ended $load_after_kill s after the kill: too little load after the failover to judge it"
moves_ok="$(jq -r '[.sessions[].moves_ok] | add' "$report")"
failed="$(jq -r '[.sessions[].errors_by_code[]] | add // 0' "$report")"
# The victim's load-test sessions after the kill: their moves, and which replicas answered them.
# nginx logs each call as it ends, with t=$msec (epoch seconds, milliseconds): a call logged after
# the kill was answered after it (the killed process answers nothing).
victim_sids="$(sed -n 's/.*sid="\([0-9a-f]*\)".*/\1/p' "$scratch/victim-moves.log" | sort -u)"
nginx_log >"$scratch/nginx-access.log"
ended_after_kill() { awk -v kill="$kill_time" '{t = $NF; sub(/^t=/, "", t); if (t + 0 > kill + 0) print}'; }
grep MoveHandles "$scratch/nginx-access.log" | grep -v "sid=\"$sid\"" | grep 'grpc_status=0' |
  ended_after_kill >"$scratch/load-ok-after-kill.log" || true
grep -F -f <(sed 's/.*/sid="&"/' <<<"$victim_sids") "$scratch/load-ok-after-kill.log" \
  >"$scratch/victim-ok-after-kill.log" || true
after_ok="$(wc -l <"$scratch/victim-ok-after-kill.log")"
[ "$after_ok" -gt 0 ] || fail "the killed replica's load-test sessions made no move after the kill"
after_on="$(while read -r line; do replica_of_line <<<"$line"; done <"$scratch/victim-ok-after-kill.log" |
  sort | uniq -c | awk '{printf "%s%s x%s", (NR > 1 ? ", " : ""), $2, $1}')"
# Per session of the victim, how long after the kill its first move was acknowledged again (the
# failover as the load tester saw it: the move in flight at the kill failed, nginx found the
# replica down, the next replica on the ring loaded the session from Redis).
resumed="$(awk -v kill="$kill_time" '{
    t = $NF; sub(/^t=/, "", t); match($0, /sid="[0-9a-f]*"/); s = substr($0, RSTART + 5, 8)
    if (!(s in first)) { first[s] = t - kill; order[++n] = s }
  } END { for (i = 1; i <= n; i++) printf "%s%s %.2f s", (i > 1 ? ", " : ""), order[i], first[order[i]] }' \
  "$scratch/victim-ok-after-kill.log")"
[ "$(awk -F', ' '{print NF}' <<<"$resumed")" -eq "$victim_sessions" ] ||
  fail "not every load-test session of the killed replica moved again after the kill: $resumed"
all_after_ok="$(wc -l <"$scratch/load-ok-after-kill.log")"
note "after the kill its $victim_sessions load-test session(s) made $after_ok more moves ($after_on);" \
  "each was first acknowledged again (session: seconds after the kill): $resumed"
note "the load ran $load_after_kill s after the kill (its move phase: $(jq -r '.phases.move_seconds | floor' "$report") s," \
  "the kill $kill_at s after the load tester started); $all_after_ok load-test moves acknowledged after it"
note "load test: $(jq -r '.sessions | length' "$report") sessions through nginx, $moves_ok moves acknowledged," \
  "$failed failed (${codes:-none}); every session closed OK; revisions add up in every session"
podman ps -a --filter "name=$(container_of "$victim")" --format '{{.Names}} {{.Status}}' >"$scratch/victim.txt"
note "the killed replica now: $(cat "$scratch/victim.txt") (restart: unless-stopped)"
commit="$(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo unknown)"
[ -z "$(git -C "$root" status --porcelain 2>/dev/null)" ] || commit="$commit + uncommitted changes"
step "PASS (commit $commit, $(date -u +%Y-%m-%dT%H:%MZ))"
