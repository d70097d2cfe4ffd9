#!/bin/sh
# The official nginx image's template step (20-envsubst-on-templates.sh), reduced to what
# compose.yaml uses: every *.template under NGINX_ENVSUBST_TEMPLATE_DIR becomes the same relative
# path without the suffix under NGINX_ENVSUBST_OUTPUT_DIR, with only the environment's variables
# substituted (nginx's own $variables stay).
set -eu
if [ "${1:-}" = "nginx" ]; then
  template_dir="${NGINX_ENVSUBST_TEMPLATE_DIR:-/etc/nginx/templates}"
  suffix="${NGINX_ENVSUBST_TEMPLATE_SUFFIX:-.template}"
  output_dir="${NGINX_ENVSUBST_OUTPUT_DIR:-/etc/nginx/conf.d}"
  defined_envs="$(printf '${%s} ' $(env | cut -d= -f1))"
  if [ -d "$template_dir" ]; then
    find "$template_dir" -follow -type f -name "*$suffix" -print | while read -r template; do
      relative_path="${template#"$template_dir/"}"
      output_path="$output_dir/${relative_path%"$suffix"}"
      mkdir -p "$(dirname "$output_path")"
      echo "$0: rendering $template to $output_path" >&2
      envsubst "$defined_envs" <"$template" >"$output_path"
    done
  fi
fi
exec "$@"
