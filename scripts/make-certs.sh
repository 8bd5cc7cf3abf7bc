#!/usr/bin/env bash
# Makes the certificates for running the services with mutual TLS (docs/security.md):
#
#   scripts/make-certs.sh DIR [NAME...]
#
# DIR/ca.pem, ca.key     a CA (made once: reused when DIR already holds one, so names can be
#                        added later)
# DIR/NAME.pem, NAME.key one certificate per service NAME, for serving and for calling the
#                        other services (SAN DNS:NAME, DNS:localhost, IP:127.0.0.1)
# DIR/picking.pem, .key  a client certificate for the `picking` command line
#
# Without names: the services of deploy/compose (simulator robot gripper scanner detector
# detector-1 detector-2 detector-3 planner orchestrator viewer). Keys are EC P-256, readable only by
# their owner; certificates are valid for DAYS days (default 825, env PICKING_CERT_DAYS).
set -euo pipefail

usage() {
  echo "usage: $0 DIR [NAME...]" >&2
  exit 2
}
[ $# -ge 1 ] || usage
case "$1" in -h | --help) usage ;; esac
command -v openssl >/dev/null || {
  echo "make-certs: openssl not installed (scripts/install-deps.sh installs it)" >&2
  exit 1
}

dir=$1
shift
names=("$@")
[ ${#names[@]} -gt 0 ] || names=(simulator robot gripper scanner detector detector-1 detector-2
  detector-3 planner orchestrator viewer)
days=${PICKING_CERT_DAYS:-825}
for name in "${names[@]}" picking; do
  # A name becomes a DNS SAN and a file name: keep to what both accept.
  [[ $name =~ ^[a-z0-9]([a-z0-9.-]*[a-z0-9])?$ ]] || {
    echo "make-certs: '$name' is not a DNS name (lower case letters, digits, '-', '.')" >&2
    exit 2
  }
done

mkdir -p "$dir"
umask 077
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# A new P-256 key in $1.
new_key() {
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null
}

if [ ! -f "$dir/ca.pem" ] || [ ! -f "$dir/ca.key" ]; then
  new_key "$dir/ca.key"
  openssl req -x509 -new -key "$dir/ca.key" -sha256 -days "$days" -subj "/CN=picking CA" \
    -addext "basicConstraints=critical,CA:TRUE" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$dir/ca.pem"
  echo "make-certs: new CA $dir/ca.pem"
fi

# sign NAME USAGE SAN: NAME.key and NAME.pem signed by the CA.
sign() {
  local name=$1 usage=$2 san=$3
  new_key "$dir/$name.key"
  openssl req -new -key "$dir/$name.key" -subj "/CN=$name" -out "$work/$name.csr"
  cat >"$work/$name.ext" <<EXT
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=$usage
subjectAltName=$san
EXT
  openssl x509 -req -in "$work/$name.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" \
    -CAcreateserial -CAserial "$work/ca.srl" -sha256 -days "$days" \
    -extfile "$work/$name.ext" -out "$dir/$name.pem" 2>/dev/null
  echo "make-certs: $dir/$name.pem"
}

for name in "${names[@]}"; do
  # serverAuth to serve, clientAuth to call the other services with the same certificate.
  sign "$name" serverAuth,clientAuth "DNS:$name,DNS:localhost,IP:127.0.0.1"
done
sign picking clientAuth "DNS:picking"
# Certificates are public; only the keys stay private.
chmod 644 "$dir"/*.pem
