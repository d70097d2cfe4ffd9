#!/usr/bin/env bash
# Makes the base images docker/Dockerfile and docker/compose.yaml name, from Debian's packages
# alone, for a machine that reaches Debian's mirror (and npm's registry, for the viewer) but no
# container registry. Each image is imported into podman's local storage under the very name a
# registry would give it, so the Dockerfile and compose.yaml need no change:
#
#   docker.io/library/debian:bookworm       debootstrap --variant=minbase bookworm
#   docker.io/library/debian:bookworm-slim  the same, with documentation, man pages and locales
#                                           left out by dpkg (as the official slim image does)
#   docker.io/library/redis:7.0.15          Debian 12's redis-server (7.0.15), run as the official
#                                           image runs it (docker/local-images/redis.Dockerfile)
#   docker.io/library/nginx:1.22.1          Debian 12's nginx (1.22.1) with the official image's
#                                           template rendering (docker/local-images/nginx.Dockerfile)
#
# The Debian 12 packages of the stand-ins are the very releases compose.yaml pins.
#
#   docker/make-base-images.sh [--force]    (as root; needs debootstrap and podman)
#
# Existing images are kept unless --force. The mirror is the one apt on this machine uses
# (/etc/apt/sources.list.d/debian.sources or /etc/apt/sources.list), and the images get the same
# apt sources (bookworm, bookworm-updates, bookworm-security), so the image's packages are the
# host's: the runtime package list derived on the host (scripts/runtime-packages.sh) installs there.
# Needs a containers.conf that suits the machine in CONTAINERS_CONF when podman's defaults do not
# (scripts/container-check.sh writes one; see docker/README.md).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
force=0
[ "${1:-}" = "--force" ] && force=1

log() { echo "make-base-images: $*" >&2; }
have_image() { [ "$force" -eq 0 ] && podman image exists "$1"; }

for tool in debootstrap podman; do
  command -v "$tool" >/dev/null || { log "$tool is missing (apt-get install $tool)"; exit 2; }
done
[ "$(id -u)" -eq 0 ] || { log "debootstrap needs root"; exit 2; }

# The first Debian mirror apt uses here, in either sources format.
mirror=""
if [ -f /etc/apt/sources.list.d/debian.sources ]; then
  mirror="$(awk '/^URIs:/ {print $2; exit}' /etc/apt/sources.list.d/debian.sources)"
fi
if [ -z "$mirror" ] && [ -f /etc/apt/sources.list ]; then
  mirror="$(awk '$1 == "deb" && $3 ~ /^bookworm$/ {print $2; exit}' /etc/apt/sources.list)"
fi
[ -n "$mirror" ] || { log "no Debian mirror found in apt's sources"; exit 2; }

scratch=""
cleanup() { if [ -n "$scratch" ]; then rm -rf "$scratch"; fi; }
trap cleanup EXIT

debian=docker.io/library/debian:bookworm
slim=docker.io/library/debian:bookworm-slim
if ! have_image "$debian" || ! have_image "$slim"; then
  scratch="$(mktemp -d /var/tmp/meshdeform-rootfs.XXXXXX)"
  rootfs="$scratch/rootfs"
  log "debootstrap bookworm from $mirror (a few minutes)"
  debootstrap --variant=minbase bookworm "$rootfs" "$mirror" >"$scratch/debootstrap.log" 2>&1 || {
    tail -20 "$scratch/debootstrap.log" >&2
    exit 1
  }
  # apt's sources as on this machine (deb822 when it has them), none of the downloaded .debs.
  rm -f "$rootfs/etc/apt/sources.list"
  if [ -f /etc/apt/sources.list.d/debian.sources ]; then
    cp /etc/apt/sources.list.d/debian.sources "$rootfs/etc/apt/sources.list.d/debian.sources"
  else
    grep -E '^deb .* bookworm(-updates|-security)?( |$)' /etc/apt/sources.list >"$rootfs/etc/apt/sources.list"
  fi
  rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/*
  # As in the official images: apt keeps no downloaded .deb files.
  printf 'DPkg::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb || true"; };\n' \
    >"$rootfs/etc/apt/apt.conf.d/docker-clean"
  log "importing $debian"
  tar -C "$rootfs" --numeric-owner -c . |
    podman import --quiet --change 'CMD ["bash"]' - "$debian" >/dev/null

  # The slim variant: dpkg leaves documentation, man pages and locales out from now on, and what
  # debootstrap already unpacked of them goes (copyright files stay).
  cat >"$rootfs/etc/dpkg/dpkg.cfg.d/docker-slim" <<'EOF'
path-exclude /usr/share/doc/*
path-include /usr/share/doc/*/copyright
path-exclude /usr/share/man/*
path-exclude /usr/share/info/*
path-exclude /usr/share/locale/*
path-exclude /usr/share/lintian/*
EOF
  find "$rootfs/usr/share/doc" -mindepth 1 -not -name copyright -not -type d -delete
  rm -rf "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/* "$rootfs"/usr/share/locale/*
  log "importing $slim"
  tar -C "$rootfs" --numeric-owner -c . |
    podman import --quiet --change 'CMD ["bash"]' - "$slim" >/dev/null
fi

# The stand-ins for the two service images compose.yaml pulls. --pull=never: they build FROM the
# slim image just imported, never from a registry.
for service in redis:7.0.15 nginx:1.22.1; do
  name="docker.io/library/$service"
  have_image "$name" && continue
  log "building $name from Debian's packages"
  build_log="$(mktemp)"
  if ! podman build --pull=never --format docker -t "$name" \
      -f "$root/docker/local-images/${service%%:*}.Dockerfile" "$root/docker/local-images" \
      >"$build_log" 2>&1; then
    tail -20 "$build_log" >&2
    rm -f "$build_log"
    exit 1
  fi
  rm -f "$build_log"
done
log "ready: $(podman images --format '{{.Repository}}:{{.Tag}}' | grep -E '^docker.io/library/(debian|redis|nginx):' | sort | tr '\n' ' ')"
