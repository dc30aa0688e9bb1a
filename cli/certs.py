"""``locnerf certs``: a test certificate authority and one certificate per service, for Zenoh TLS.

Every certificate's common name (CN) is its role (``router``, ``ingest``, ``filter``, ``worker``,
``operator``, ``robot``): the router's access control (``deploy/zenoh/router-tls.json5``) grants
publications by CN. Each certificate names ``localhost``, ``127.0.0.1`` and the docker compose
service names as subject alternative names, so that one set serves loopback tests and compose.
The keys are written unencrypted (mode 0600): these are test and lab certificates; a fleet uses
its own PKI with the same CNs.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import logging
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from locnerf.errors import LocnerfInputError

logger = logging.getLogger(__name__)

ROLES = ("router", "ingest", "filter", "worker", "operator", "robot")
"""Default certificates: the router, the three services, the operator (commands) and the robot (pose reader)."""

DNS_NAMES = ("localhost", "zenohd", "ingest", "filter", "worker", "worker-cuda")
"""Subject alternative names of every certificate: loopback and the compose service names."""

IP_ADDRESSES = ("127.0.0.1", "::1")


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "locnerf"), x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    path.write_bytes(pem)
    os.chmod(path, 0o600)


def make_certificates(out: Path, roles: tuple[str, ...] = ROLES, days: int = 365) -> list[Path]:
    """Write ``ca.pem``, ``ca-key.pem`` and ``<role>.pem`` / ``<role>-key.pem`` for each role.

    Args:
        out: folder (created).
        roles: common names, one certificate each.
        days: validity from now.

    Returns:
        The files written.

    Raises:
        LocnerfInputError: an empty or duplicated role, or ``days`` < 1.
    """
    if days < 1:
        raise LocnerfInputError(f"certificate validity {days} days: expected >= 1")
    if not roles or len(set(roles)) != len(roles) or not all(role.strip() for role in roles):
        raise LocnerfInputError(f"roles {roles!r}: expected distinct, non-empty common names")
    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(_name("locnerf test CA"))
        .issuer_name(_name("locnerf test CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    written = [out / "ca.pem", out / "ca-key.pem"]
    written[0].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    _write_key(written[1], ca_key)
    alternative_names = [x509.DNSName(name) for name in DNS_NAMES] + [x509.IPAddress(ipaddress.ip_address(a)) for a in IP_ADDRESSES]
    for role in roles:
        key = ec.generate_private_key(ec.SECP256R1())
        certificate = (
            x509.CertificateBuilder()
            .subject_name(_name(role))
            .issuer_name(ca.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start)
            .not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(True, False, False, False, False, False, False, False, False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.SubjectAlternativeName(alternative_names), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        certificate_path, key_path = out / f"{role}.pem", out / f"{role}-key.pem"
        certificate_path.write_bytes(certificate.public_bytes(serialization.Encoding.PEM))
        _write_key(key_path, key)
        written += [certificate_path, key_path]
    logger.info("wrote a CA and %d certificates to %s", len(roles), out)
    return written


def run(args: argparse.Namespace) -> int:
    """Write the certificates and list them."""
    for path in make_certificates(args.out, tuple(args.roles), args.days):
        print(path)
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf certs``."""
    parser.add_argument("--out", type=Path, default=Path("deploy/certs"), help="folder to write into (default deploy/certs)")
    parser.add_argument("--roles", nargs="+", default=list(ROLES), help=f"common names to certify (default: {' '.join(ROLES)})")
    parser.add_argument("--days", type=int, default=365, help="validity in days (default 365)")
    parser.set_defaults(func=run)
