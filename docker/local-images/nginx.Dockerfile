# A local stand-in for the official nginx:1.22.1 image, from Debian 12's nginx (1.22.1, the release
# compose.yaml pins and the scale-out test runs), for machines without registry access
# (docker/make-base-images.sh builds it as docker.io/library/nginx:1.22.1). It behaves as the
# official image does where compose.yaml relies on it: the entrypoint renders
# /etc/nginx/templates/*.template with envsubst (only variables set in the environment) into
# NGINX_ENVSUBST_OUTPUT_DIR (default /etc/nginx/conf.d), then runs nginx in the foreground;
# /var/cache/nginx exists for temporary files; SIGQUIT stops it gracefully.
FROM docker.io/library/debian:bookworm-slim
ENV DEBIAN_FRONTEND=noninteractive
RUN printf '#!/bin/sh\nexit 101\n' >/usr/sbin/policy-rc.d && chmod 0755 /usr/sbin/policy-rc.d \
 && apt-get update -qq \
 && apt-get install -y -qq --no-install-recommends nginx gettext-base >/dev/null \
 && rm -rf /var/lib/apt/lists/* /usr/sbin/policy-rc.d /etc/nginx/sites-enabled/default \
 && install -d -m 0755 /var/cache/nginx /etc/nginx/templates \
 && ln -sf /dev/stdout /var/log/nginx/access.log && ln -sf /dev/stderr /var/log/nginx/error.log
COPY nginx-entrypoint.sh /docker-entrypoint.sh
EXPOSE 80
STOPSIGNAL SIGQUIT
ENTRYPOINT ["/docker-entrypoint.sh"]
CMD ["nginx", "-g", "daemon off;"]
