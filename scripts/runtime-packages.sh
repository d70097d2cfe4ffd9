#!/usr/bin/env bash
# The Debian packages a binary needs at run time, derived from the binary itself: every shared
# library the dynamic loader resolves for it (its NEEDED entries and theirs, transitively, as
# `ldd` lists them) mapped to the installed package that owns the file (`dpkg-query -S`).
# docker/Dockerfile's runtime stage installs docker/runtime-packages.txt, which this script
# writes; the image build and the test command (tests/docker) check it against the Release
# meshdeform-server, so a new library dependency cannot be forgotten in the image.
#
#   scripts/runtime-packages.sh BINARY                 the packages, one per line, sorted
#   scripts/runtime-packages.sh --explain BINARY       each library: NEEDED or transitive,
#                                                      the file it resolves to, its package
#   scripts/runtime-packages.sh --write LIST BINARY    rewrite LIST (docker/runtime-packages.txt)
#   scripts/runtime-packages.sh --check LIST BINARY    exit 1 when LIST lacks a package the binary
#                                                      needs (naming the libraries that need it) or
#                                                      holds one it does not need
#
# Exit codes: 0 ok, 1 the check failed, 2 usage or the binary cannot be mapped (not a dynamic
# executable, a library `ldd` cannot find, a library no installed package owns).
# Run it on the machine that built the binary (Debian 12, as the image's builder stage is): the
# packages are the ones installed there. Libraries loaded with dlopen() are invisible to ldd; the
# server loads none (`ldd` is the whole list), and its non-library run-time needs
# (ca-certificates for rediss://, curl for the HEALTHCHECK) are named in the Dockerfile itself.
set -euo pipefail

usage() {
  sed -n '8,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
}
fail() {
  echo "runtime-packages: $*" >&2
  exit 2
}

mode=print
list=""
case "${1:-}" in
  --explain) mode=explain; shift ;;
  --write | --check)
    mode="${1#--}"
    [ $# -ge 2 ] || usage
    list="$2"
    shift 2
    ;;
  -h | --help | "") usage ;;
esac
[ $# -eq 1 ] || usage
binary="$1"
[ -f "$binary" ] || fail "$binary: no such file"
[ "$mode" != check ] || [ -f "$list" ] || fail "$list: no such file"
command -v ldd >/dev/null || fail "ldd is missing (Debian package libc-bin)"
command -v dpkg-query >/dev/null || fail "dpkg-query is missing: this needs a Debian system"

# The direct dependencies, to tell NEEDED from transitive in --explain and in the check's message.
declare -A needed=()
if command -v readelf >/dev/null; then
  while read -r name; do needed["$name"]=1; done < <(
    readelf -d "$binary" 2>/dev/null | sed -n 's/.*(NEEDED).*\[\(.*\)\]$/\1/p')
fi

# ldd's lines: "libfoo.so.1 => /path/libfoo.so.1 (0x...)", "/lib64/ld-linux-x86-64.so.2 (0x...)",
# "linux-vdso.so.1 (0x...)" (in the kernel: no file), or "libbar.so.2 => not found".
if ! ldd_out="$(LC_ALL=C ldd "$binary" 2>&1)"; then
  fail "ldd $binary failed: $ldd_out"
fi
case "$ldd_out" in
  *"not a dynamic executable"*) fail "$binary is not a dynamic executable" ;;
esac
names=()
paths=()
missing_libs=()
while IFS= read -r line; do
  line="${line#"${line%%[![:space:]]*}"}"
  if [[ "$line" =~ ^([^[:space:]]+)\ =\>\ not\ found ]]; then
    missing_libs+=("${BASH_REMATCH[1]}")
  elif [[ "$line" =~ ^([^[:space:]]+)\ =\>\ (/[^[:space:]]+)\ \( ]]; then
    names+=("${BASH_REMATCH[1]}")
    paths+=("${BASH_REMATCH[2]}")
  elif [[ "$line" =~ ^(/[^[:space:]]+)\ \( ]]; then
    names+=("${BASH_REMATCH[1]##*/}")
    paths+=("${BASH_REMATCH[1]}")
  fi
done <<<"$ldd_out"
if [ ${#missing_libs[@]} -gt 0 ]; then
  fail "$binary needs libraries this machine does not have: ${missing_libs[*]} (ldd: not found)"
fi
[ ${#paths[@]} -gt 0 ] || fail "ldd listed no library for $binary"

# dpkg records each file under the path its package ships it at; the loader may have found it
# through the other side of the merged /usr (/lib -> usr/lib) or through a symlink (the
# libblas.so.3 alternative points into openblas-pthread/). Candidates per library, in order: the
# path, its /usr twin, the symlink's target, the target's /usr twin.
# (No subshell per library: this runs in the test command, on a busy machine.)
usr_twin() {  # sets twin to the other side of the merged /usr
  if [[ "$1" == /usr/* ]]; then twin="${1#/usr}"; else twin="/usr$1"; fi
}
mapfile -t reals < <(readlink -f -- "${paths[@]}")
[ ${#reals[@]} -eq ${#paths[@]} ] || fail "readlink -f could not resolve every library path"
declare -a candidates=()
for i in "${!paths[@]}"; do
  usr_twin "${paths[$i]}"
  path_twin="$twin"
  usr_twin "${reals[$i]}"
  candidates+=("${paths[$i]}" "$path_twin" "${reals[$i]}" "$twin")
done
# One dpkg-query for every candidate (it exits 1 when some have no owner; those are expected).
declare -A owner=()
while IFS= read -r line; do
  case "$line" in diversion\ by* | *"no path found"*) continue ;; esac
  file="${line#*: }"
  pkgs="${line%%: *}"
  owner["$file"]="$pkgs"
done < <(LC_ALL=C dpkg-query -S "${candidates[@]}" 2>/dev/null || true)

declare -A package_of=()     # library name -> package
declare -A libs_of=()        # package -> its libraries (space separated)
unowned=()
for i in "${!paths[@]}"; do
  pkg=""
  for c in "${candidates[@]:$((i * 4)):4}"; do
    if [ -n "${owner[$c]:-}" ]; then
      pkg="${owner[$c]}"
      break
    fi
  done
  if [ -z "$pkg" ]; then
    unowned+=("${paths[$i]}")
    continue
  fi
  # "libc6:amd64" -> "libc6"; several owners ("a, b") cannot happen for a library file, but
  # would be taken whole: the first.
  pkg="${pkg%%,*}"
  pkg="${pkg%%:*}"
  package_of["${names[$i]}"]="$pkg"
  libs_of["$pkg"]="${libs_of[$pkg]:-}${libs_of[$pkg]:+ }${names[$i]}"
done
if [ ${#unowned[@]} -gt 0 ]; then
  fail "no installed Debian package owns ${unowned[*]} (built or copied by hand?): the image cannot install it"
fi
mapfile -t packages < <(printf '%s\n' "${!libs_of[@]}" | LC_ALL=C sort)

list_packages() {  # the package names in a list file: no comments, no blank lines
  sed -e 's/#.*//' -e 's/[[:space:]]//g' "$1" | sed '/^$/d'
}

case "$mode" in
  print) printf '%s\n' "${packages[@]}" ;;
  explain)
    for i in "${!names[@]}"; do
      kind=transitive
      [ -n "${needed[${names[$i]}]:-}" ] && kind=NEEDED
      printf '%-10s %-45s %-70s %s\n' "$kind" "${names[$i]}" "${paths[$i]}" \
        "${package_of[${names[$i]}]}"
    done
    ;;
  write)
    {
      echo "# The Debian packages of every shared library meshdeform-server loads (ldd of the"
      echo "# Release build on Debian 12, mapped with dpkg-query -S). docker/Dockerfile's runtime stage"
      echo "# installs exactly these. Generated: do not edit by hand; after a dependency change run"
      echo "#   scripts/runtime-packages.sh --write docker/runtime-packages.txt build/server/transport/meshdeform-server"
      echo "# The test command checks it (RuntimePackagesTest), and so does the image build."
      printf '%s\n' "${packages[@]}"
    } >"$list"
    echo "runtime-packages: wrote ${#packages[@]} packages to $list" >&2
    ;;
  check)
    declare -A listed=()
    while read -r p; do listed["$p"]=1; done < <(list_packages "$list")
    status=0
    for p in "${packages[@]}"; do
      if [ -z "${listed[$p]:-}" ]; then
        libs=""
        for lib in ${libs_of[$p]}; do
          if [ -n "${needed[$lib]:-}" ]; then libs+=" $lib (NEEDED)"; else libs+=" $lib"; fi
        done
        echo "runtime-packages: $list lacks $p, which provides:$libs" >&2
        status=1
      fi
      unset "listed[$p]"
    done
    for p in "${!listed[@]}"; do
      echo "runtime-packages: $list names $p, which $(basename "$binary") does not load" >&2
      status=1
    done
    if [ "$status" -ne 0 ]; then
      echo "runtime-packages: regenerate it: scripts/runtime-packages.sh --write $list $binary" >&2
      exit 1
    fi
    echo "runtime-packages: $list covers the ${#packages[@]} packages of the ${#names[@]} libraries $(basename "$binary") loads" >&2
    ;;
esac
