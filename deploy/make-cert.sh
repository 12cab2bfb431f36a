#!/usr/bin/env bash
# Makes a self-signed TLS certificate and key for imucald, when there is none yet:
#   deploy/make-cert.sh DIR [NAME...]
# writes DIR/server.crt (0644) and DIR/server.key (0600): ECDSA P-256, valid 825 days, for
# localhost, 127.0.0.1, ::1, this host's names and every NAME (a DNS name or an IP address).
# Does nothing if DIR/server.crt exists. Clients trust it with `--ca DIR/server.crt`.
# For a fleet, use certificates from your own CA instead (README "Deployment").
set -euo pipefail
dir="${1:?usage: make-cert.sh DIR [NAME...]}"
shift
if [ -e "$dir/server.crt" ]; then
  echo "make-cert: $dir/server.crt exists; left as it is"
  exit 0
fi
command -v openssl >/dev/null || { echo "make-cert: openssl is not installed" >&2; exit 1; }
mkdir -p "$dir"
san="DNS:localhost,IP:127.0.0.1,IP:::1"
names=("$@")
short="$(hostname 2>/dev/null || true)"
full="$(hostname -f 2>/dev/null || true)"
for n in "$short" "$full"; do
  [ -n "$n" ] && [ "$n" != localhost ] && names+=("$n")
done
declare -A seen=()
for n in "${names[@]}"; do
  [ -n "${seen[$n]:-}" ] && continue
  seen[$n]=1
  if [[ "$n" =~ ^[0-9.]+$ || "$n" == *:* ]]; then san="$san,IP:$n"; else san="$san,DNS:$n"; fi
done
cn="${names[0]:-localhost}"
umask 077
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 825 \
  -subj "/CN=$cn" -addext "subjectAltName=$san" -addext "basicConstraints=critical,CA:TRUE" \
  -addext "keyUsage=critical,digitalSignature,keyCertSign" -addext "extendedKeyUsage=serverAuth" \
  -keyout "$dir/server.key.tmp" -out "$dir/server.crt.tmp" 2>/dev/null
chmod 0600 "$dir/server.key.tmp"
chmod 0644 "$dir/server.crt.tmp"
mv "$dir/server.key.tmp" "$dir/server.key"
mv "$dir/server.crt.tmp" "$dir/server.crt"
echo "make-cert: wrote $dir/server.crt and $dir/server.key (self-signed; names: $san)"
