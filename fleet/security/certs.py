"""``fleet certs``: a CA and one certificate per principal of the inventory, for mutual TLS.

A test and small-site CA: one self-signed authority (``ca.pem``, its key ``ca.key``, keep that
one offline), and for every principal ``<principal>.pem`` + ``<principal>.key`` whose common
name is the principal (the router's access control matches it). The router's certificate also
names the hosts of the inventory's endpoints, which clients verify. Existing files are kept
(an existing CA signs the missing certificates) unless ``force``. Also writes ``passwords.txt``
(``user:password`` lines, random) for ``mode = "password"``. Private keys are mode 0600.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import secrets
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from fleet.files import read_regular
from fleet.inventory import Inventory

CA_NAME = "d1-fleet CA"
PEM_MAX_BYTES = 64 * 1024
"""A PEM certificate or key we write is about 1 KB."""


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    data = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    _write_secret(path, data)


def _write_secret(path: Path, data: bytes) -> None:
    """Write a key or the password file with mode 0600, also over an existing file (once
    ``fleet certs --force`` kept a 0644 key 0644): the mode is set on the open descriptor
    before a byte is written."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "wb") as out:
        os.fchmod(out.fileno(), 0o600)
        out.write(data)


def _write_cert(path: Path, cert: x509.Certificate) -> None:
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _load_ca(out: Path) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey] | None:
    cert, key = out / "ca.pem", out / "ca.key"
    if not (cert.is_file() and key.is_file()):
        return None
    # Bounded reads (fleet/files.py): a FIFO or a huge file in its place is refused, not read.
    loaded = serialization.load_pem_private_key(
        read_regular(key, PEM_MAX_BYTES, "CA key"), password=None
    )
    assert isinstance(loaded, ec.EllipticCurvePrivateKey), "ca.key is not an EC key"
    pem = read_regular(cert, PEM_MAX_BYTES, "CA certificate")
    return x509.load_pem_x509_certificate(pem), loaded


def _new_ca(out: Path, days: int) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    usage = x509.KeyUsage(
        digital_signature=True,
        key_cert_sign=True,
        crl_sign=True,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        encipher_only=False,
        decipher_only=False,
    )
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name(CA_NAME))
        .issuer_name(_name(CA_NAME))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(usage, critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_key(out / "ca.key", key)
    _write_cert(out / "ca.pem", cert)
    return cert, key


def _hosts(inventory: Inventory) -> list[x509.GeneralName]:
    """The router's names: localhost, 127.0.0.1 and every endpoint's host."""
    names: list[x509.GeneralName] = [
        x509.DNSName("localhost"),
        x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
    ]
    for endpoint in inventory.endpoints:
        host = endpoint.split("/", 1)[-1].rpartition(":")[0].strip("[]")
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return list(dict.fromkeys(names))


def _issue(
    out: Path,
    principal: str,
    ca: tuple[x509.Certificate, ec.EllipticCurvePrivateKey],
    days: int,
    hosts: list[x509.GeneralName],
) -> None:
    ca_cert, ca_key = ca
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    uses = [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH]
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(principal))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage(uses), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
    )
    if hosts:
        builder = builder.add_extension(x509.SubjectAlternativeName(hosts), critical=False)
    _write_key(out / f"{principal}.key", key)
    _write_cert(out / f"{principal}.pem", builder.sign(ca_key, hashes.SHA256()))


def make_certs(
    inventory: Inventory, out: str | Path, days: int = 365, force: bool = False
) -> list[str]:
    """Write the CA (if missing) and every principal's certificate; returns what was written."""
    directory = Path(out)
    directory.mkdir(parents=True, exist_ok=True)
    ca = None if force else _load_ca(directory)
    written = []
    if ca is None:
        ca = _new_ca(directory, days)
        written.append("ca.pem")
        force = True  # a new CA: every certificate must be signed by it
    hosts = _hosts(inventory)
    for principal in sorted(inventory.principals):
        if force or not (directory / f"{principal}.pem").is_file():
            names = hosts if inventory.principals[principal] == "router" else []
            _issue(directory, principal, ca, days, names)
            written.append(f"{principal}.pem")
    passwords = directory / "passwords.txt"
    known = {}
    if passwords.is_file() and not force:
        known = dict(
            line.split(":", 1)
            for line in read_regular(passwords, what="passwords file")
            .decode("utf-8", "replace")
            .splitlines()
            if ":" in line
        )
    lines = [
        f"{p}:{known.get(p) or secrets.token_urlsafe(18)}" for p in sorted(inventory.principals)
    ]
    _write_secret(passwords, ("\n".join(lines) + "\n").encode())
    return written
