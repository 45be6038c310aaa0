"""``poseidon certs --out DIR --hosts a,b[,...] [--days N]``: the keys of a secured deployment.

Writes a certificate authority (``ca.pem``, ``ca.key``: keep the key offline) and, for each
computer, ``<host>.pem`` / ``<host>.key``: an ECDSA P-256 certificate signed by the CA whose
common name and subject alternative name are the host name (and its IP address when the
name is one, plus localhost/127.0.0.1 for the services of that computer), usable both as TLS server (its router listens) and client (it connects).
Zenoh's mutual TLS (``deploy/zenoh/secured-*.json5``) accepts a peer only with a
certificate of this CA; access control can then name computers by ``cert_common_names``.
Private keys are written with mode 0600.

It also writes the user/password credentials of the secured profile: ``users.txt`` (the
routers' ``transport.auth.usrpwd.dictionary_file``, one ``user:password`` a line) and
``<user>.password`` for each of :data:`USERS` (the service of that name reads it with
``poseidon service NAME --zenoh-user NAME --zenoh-password-file DIR/NAME.password``);
passwords are 32 random URL-safe characters (``secrets``).  Exit 2 on bad arguments or
when DIR already holds any of these files (keys are never overwritten).
"""
from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import sys
from pathlib import Path

__all__ = ["make_ca", "make_host_cert", "write_credentials", "USERS", "main"]

#: users of the secured profile: every service, and ``router`` for router-to-router links
USERS = ("router", "player", "recorder", "encoder", "htm", "robot_state", "posecells", "expmap")


def write_credentials(out: Path, users: tuple[str, ...] = USERS) -> None:
    """``users.txt`` (router dictionary) and ``<user>.password`` files, mode 0600."""
    import secrets
    pw = {u: secrets.token_urlsafe(24) for u in users}
    for u, p in pw.items():
        fd = os.open(out / f"{u}.password", os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(p + "\n")
    fd = os.open(out / "users.txt", os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write("".join(f"{u}:{p}\n" for u, p in pw.items()))


def _name(cn: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "PoseidonSLAM"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _write_key(path: Path, key) -> None:
    from cryptography.hazmat.primitives import serialization
    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _write_cert(path: Path, cert) -> None:
    from cryptography.hazmat.primitives import serialization
    with open(path, "xb") as f:
        f.write(cert.public_bytes(serialization.Encoding.PEM))


def make_ca(days: int = 3650, name: str = "PoseidonSLAM CA"):
    """A self-signed CA certificate and its key."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(_name(name)).issuer_name(_name(name))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    return cert, key


def make_host_cert(host: str, ca_cert, ca_key, days: int = 3650):
    """A certificate for computer ``host`` (CN and SAN), signed by the CA."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.timezone.utc)
    try:
        alt: list = [x509.IPAddress(ipaddress.ip_address(host))]  # an IP is never a DNSName (rustls rejects it)
    except ValueError:
        alt = [x509.DNSName(host)]
    # services reach their own computer's router on loopback
    alt += [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
    cert = (x509.CertificateBuilder().subject_name(_name(host)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .sign(ca_key, hashes.SHA256()))
    return cert, key


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon certs", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for ca.pem/ca.key and <host>.pem/<host>.key")
    ap.add_argument("--hosts", required=True, help="comma-separated computer names or IP addresses")
    ap.add_argument("--days", type=int, default=3650, help="validity (days)")
    args = ap.parse_args(argv)
    hosts = [h.strip() for h in args.hosts.split(",") if h.strip()]
    bad = [h for h in hosts if not all(c.isalnum() or c in ".-_:" for c in h)]
    if not hosts or bad or len(set(hosts)) != len(hosts) or "ca" in hosts:
        print(f"poseidon certs: --hosts must list distinct names (letters, digits, . - _ :), not 'ca'; got {hosts}",
              file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    planned = ([out / "ca.pem", out / "ca.key", out / "users.txt"] + [out / f"{u}.password" for u in USERS]
               + [out / f"{h}.{e}" for h in hosts for e in ("pem", "key")])
    existing = [p.name for p in planned if p.exists()]
    if existing:
        print(f"poseidon certs: {out} already holds {existing}; refusing to overwrite keys", file=sys.stderr)
        return 2
    ca_cert, ca_key = make_ca(args.days)
    _write_cert(out / "ca.pem", ca_cert)
    _write_key(out / "ca.key", ca_key)
    for h in hosts:
        cert, key = make_host_cert(h, ca_cert, ca_key, args.days)
        _write_cert(out / f"{h}.pem", cert)
        _write_key(out / f"{h}.key", key)
    write_credentials(out)
    print(f"wrote {out}/ca.pem (+ ca.key: keep it offline), a certificate per computer "
          f"({', '.join(h + '.pem' for h in hosts)}), users.txt and one .password per service", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
