#!/usr/bin/env bash
# Installs the Debian 12 packages meshdeform builds and tests with, plus any package names given
# as arguments (scripts/install-fuzz-deps.sh passes clang's). Idempotent: does nothing when
# everything is already there, so it is cheap to call from every entry script.
set -euo pipefail

packages=(
  cmake g++ make pkg-config
  ccache  # repeated builds on one machine (CMakeLists.txt, MESHDEFORM_CCACHE)
  lld  # the linker (CMakeLists.txt, MESHDEFORM_LLD)
  libeigen3-dev libtinygltf-dev nlohmann-json3-dev
  libsuitesparse-dev libopenblas-dev libopenblas0-pthread
  libgtest-dev libgmock-dev libbenchmark-dev
  libcgal-dev libopenmesh-dev  # OpenMesh: irregular remeshing and subdivision in core/samples/
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libboost-dev libmeshoptimizer-dev libssl-dev openssl
  libzstd-dev  # link-sized vertex updates (codec/update_codec.cpp)
  libcli11-dev  # the command-line tools' flag parsing (common/command_line.h)
  nginx  # tests/scaleout: nginx in front of replicas (no daemon is started without systemd)
  procps  # scripts/kill-check.sh: pgrep finds the test's server child
  libhiredis-dev  # --redis: sessions on Redis (server/redis/)
  redis-server  # tests/redis start their own on a loopback port (no daemon without systemd)
  "$@"
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi

echo "meshdeform: installing ${missing[*]}" >&2
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "meshdeform: run as root or install sudo" >&2; exit 1; }
  sudo_cmd=(sudo)
fi
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
