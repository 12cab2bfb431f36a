#!/bin/sh
# imucald's container entrypoint: makes a self-signed certificate on the data volume the first
# time (unless TLS files are provided or IMUCALD_INSECURE is set), then runs imucald as PID 1's
# PID 1 (exec), so that `docker stop`'s SIGTERM reaches it and it drains.
#   docker run ... imucald:latest [imucald flags]
#   docker run ... imucald:latest backup --out-dir /var/lib/imucald/backups
set -eu
case "${1:-}" in
  backup|restore|--health-check|--help|-h) exec /usr/local/bin/imucald "$@" ;;
esac
if [ "${IMUCALD_INSECURE:-false}" != "true" ] && [ ! -e "${IMUCALD_TLS_CERT}" ]; then
  dir="$(dirname "${IMUCALD_TLS_CERT}")"
  /usr/local/share/imucald/make-cert.sh "$dir" ${IMUCALD_TLS_NAMES:-}
  [ "$dir/server.key" = "${IMUCALD_TLS_KEY}" ] || cp "$dir/server.key" "${IMUCALD_TLS_KEY}"
fi
exec /usr/local/bin/imucald "$@"
