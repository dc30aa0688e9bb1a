"""``locnerf certs``: a CA and per-role certificates whose CN is the role, valid for loopback and compose names."""

from __future__ import annotations

import ipaddress
import stat

import pytest
from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from locnerf_cli.certs import make_certificates
from locnerf_cli.main import main


def test_certificates_are_signed_by_the_ca_with_the_role_as_common_name(tmp_path):
    assert main(["certs", "--out", str(tmp_path), "--roles", "router", "operator", "--days", "2"]) == 0
    ca = x509.load_pem_x509_certificate((tmp_path / "ca.pem").read_bytes())
    for role in ("router", "operator"):
        certificate = x509.load_pem_x509_certificate((tmp_path / f"{role}.pem").read_bytes())
        assert certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        certificate.verify_directly_issued_by(ca)
        names = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert {"localhost", "zenohd", "filter"} <= set(names.get_values_for_type(x509.DNSName))
        assert ipaddress.ip_address("127.0.0.1") in names.get_values_for_type(x509.IPAddress)
        assert stat.S_IMODE((tmp_path / f"{role}-key.pem").stat().st_mode) == 0o600
    assert isinstance(ca.public_key(), ec.EllipticCurvePublicKey)
    assert not (tmp_path / "worker.pem").exists()


@pytest.mark.parametrize("roles, days, message", [((), 30, "distinct, non-empty"), (("a", "a"), 30, "distinct"), (("a",), 0, "validity 0 days")])
def test_bad_arguments_are_refused(tmp_path, roles, days, message):
    with pytest.raises(ValueError, match=message):
        make_certificates(tmp_path, roles, days)
