#!/bin/sh
# Test certificates for the mTLS profile: a CA, the router's certificate and one client
# certificate per identity (its common name is what access control matches).
#
#   deploy/zenoh/secure/make-certs.sh OUTDIR SAN CN [CN...]
#   deploy/zenoh/secure/make-certs.sh /etc/stereovox/tls IP:127.0.0.1,DNS:localhost car monitor
#
# SAN lists every name clients use to reach the router (rustls checks it). Writes ca.pem, ca.key,
# router.pem, router.key and CN.pem, CN.key per identity, keys readable by the owner only. For a
# vehicle, keep ca.key off the vehicle; never commit any of these files.
set -eu
[ $# -ge 3 ] || { sed -n '2,10p' "$0"; exit 2; }
out=$1 san=$2
shift 2
mkdir -p "$out"
umask 077
days=825
ext=$(mktemp)
trap 'rm -f "$ext" "$out"/*.csr' EXIT

key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }

key "$out/ca.key"
openssl req -x509 -new -key "$out/ca.key" -sha256 -days "$days" -subj "/CN=stereovox test CA" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$out/ca.pem"

# sign NAME CN EXTENSIONS: a leaf certificate signed by the CA
sign() {
    key "$out/$1.key"
    openssl req -new -key "$out/$1.key" -subj "/CN=$2" -out "$out/$1.csr"
    printf '%s\n' "basicConstraints=critical,CA:FALSE" "keyUsage=critical,digitalSignature" "$3" > "$ext"
    openssl x509 -req -in "$out/$1.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
        -sha256 -days "$days" -extfile "$ext" -out "$out/$1.pem" 2>/dev/null
}

sign router router "extendedKeyUsage=serverAuth
subjectAltName=$san"
for cn in "$@"; do
    sign "$cn" "$cn" "extendedKeyUsage=clientAuth"
done
chmod 644 "$out"/*.pem
rm -f "$out/ca.srl"
echo "certificates in $out: ca.pem router.pem $(printf '%s.pem ' "$@")"
