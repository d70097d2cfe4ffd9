# A local stand-in for the official redis:7.0.15 image, from Debian 12's redis-server (7.0.15, the
# release compose.yaml pins), for machines without registry access (docker/make-base-images.sh
# builds it as docker.io/library/redis:7.0.15). It behaves as the official image does where
# compose.yaml relies on it: `redis-server ARGS...` runs as the unprivileged user redis in /data
# (the volume), protected mode is off by default (the official build compiles it off: other
# containers reach Redis over the compose network without a password), redis-cli is there for the
# health check, port 6379.
FROM docker.io/library/debian:bookworm-slim
ENV DEBIAN_FRONTEND=noninteractive
# policy-rc.d: the package's postinst must not start a daemon inside the build.
RUN printf '#!/bin/sh\nexit 101\n' >/usr/sbin/policy-rc.d && chmod 0755 /usr/sbin/policy-rc.d \
 && apt-get update -qq \
 && apt-get install -y -qq --no-install-recommends redis-server redis-tools >/dev/null \
 && rm -rf /var/lib/apt/lists/* /usr/sbin/policy-rc.d \
 && install -d -o redis -g redis -m 0755 /data
COPY redis-entrypoint.sh /usr/local/bin/docker-entrypoint.sh
VOLUME /data
WORKDIR /data
EXPOSE 6379
ENTRYPOINT ["/usr/local/bin/docker-entrypoint.sh"]
CMD ["redis-server"]
