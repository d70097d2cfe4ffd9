#!/bin/sh
# The official redis image's entrypoint, reduced to what compose.yaml uses: flags alone mean
# redis-server; as root, /data is handed to the redis user and the server drops to it; protected
# mode defaults to off (an explicit --protected-mode or a config file's setting still wins).
set -e
case "$1" in
  -* | *.conf) set -- redis-server "$@" ;;
esac
if [ "$1" = "redis-server" ]; then
  shift
  conf=""
  case "$1" in
    *.conf) conf="$1"; shift ;;
  esac
  set -- redis-server ${conf:+"$conf"} --protected-mode no "$@"
  if [ "$(id -u)" = "0" ]; then
    find . \! -user redis -exec chown redis '{}' +
    umask 0077
    exec setpriv --reuid=redis --regid=redis --init-groups "$@"
  fi
fi
umask 0077
exec "$@"
