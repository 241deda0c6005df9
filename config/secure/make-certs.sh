#!/bin/sh
# Make a private CA and one certificate per node for pivotd's mutual-TLS profile (docs/SECURITY.md).
#
#   make-certs.sh DIR NAME [NAME ...]
#
# writes DIR/ca.pem (+ DIR/ca.key: keep it offline) and DIR/NAME.pem + DIR/NAME.key for each NAME, which is
# the certificate's common name (what zenoh.security.allow_cert_common_names lists). Every certificate is
# valid for the host names NAME and localhost and the address 127.0.0.1, plus whatever PIVOTD_CERT_SAN adds
# (e.g. PIVOTD_CERT_SAN="DNS:robot.local,IP:10.0.0.5"). An existing CA in DIR is reused.
set -eu
if [ $# -lt 2 ]; then
    echo "usage: $0 DIR NAME [NAME ...]" >&2
    exit 2
fi
dir=$1
shift
days=${PIVOTD_CERT_DAYS:-825}
mkdir -p "$dir"
umask 077
if [ ! -f "$dir/ca.pem" ]; then
    openssl req -x509 -newkey rsa:2048 -nodes -sha256 -days "$days" -subj "/CN=pivotd-ca" \
        -keyout "$dir/ca.key" -out "$dir/ca.pem" 2>/dev/null
fi
for name in "$@"; do
    san="DNS:$name,DNS:localhost,IP:127.0.0.1${PIVOTD_CERT_SAN:+,$PIVOTD_CERT_SAN}"
    ext="$dir/$name.ext"
    printf 'subjectAltName=%s\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" > "$ext"
    openssl req -newkey rsa:2048 -nodes -sha256 -subj "/CN=$name" -keyout "$dir/$name.key" \
        -out "$dir/$name.csr" 2>/dev/null
    openssl x509 -req -sha256 -days "$days" -in "$dir/$name.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" \
        -CAcreateserial -extfile "$ext" -out "$dir/$name.pem" 2>/dev/null
    rm -f "$dir/$name.csr" "$ext"
done
chmod 644 "$dir/ca.pem" "$dir"/*.pem
