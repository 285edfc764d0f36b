"""Who may connect to the simulated OPC UA PLC: its certificates, the one trusted client, the one user.

The server offers only the policy and mode the driver's settings name
(:data:`POLICIES`), trusts exactly the client certificate those settings
name (:class:`TrustOne`) and lets in only their username with the password
the driver reads (:class:`OneUser`).

A fresh demo config names certificate files that do not exist yet: the
server's pair and the client's pair are generated here (asyncua's
``cert_gen``, self-signed, valid for :data:`CERTIFICATE_DAYS`) and saved
where the settings name them, PEM or DER by suffix as the driver reads them.
Existing files are used as they are; a half pair is an error naming the fix.
Certificates are loaded with the driver's own
:func:`~compd.drivers.opcua.security.load_certificate`.
"""

from __future__ import annotations

import hmac
import ipaddress
import socket
from pathlib import Path
from typing import Any

import structlog
from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto import cert_gen
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from asyncua.server.user_managers import UserManager
from asyncua.ua.status_codes import StatusCodes
from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.hazmat.primitives.serialization import (
    Encoding,
    NoEncryption,
    PrivateFormat,
    load_der_private_key,
)
from cryptography.x509.oid import ExtendedKeyUsageOID

from compd.drivers.opcua.security import load_certificate
from compd.errors import DriverError

log = structlog.get_logger("compd.sim.plc.opcua")

#: Application URI of a server whose certificate is generated here.
SERVER_URI = "urn:compd:sim:plc"
#: The server's one endpoint policy for each ``(security.policy, security.mode)``.
POLICIES = {
    ("Basic256Sha256", "SignAndEncrypt"): ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    ("Basic256Sha256", "Sign"): ua.SecurityPolicyType.Basic256Sha256_Sign,
    ("Aes256_Sha256_RsaPss", "SignAndEncrypt"): (
        ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt
    ),
    ("Aes256_Sha256_RsaPss", "Sign"): ua.SecurityPolicyType.Aes256Sha256RsaPss_Sign,
}
#: Validity of generated certificates: a demo machine should not expire under its user.
CERTIFICATE_DAYS = 3650
#: Application URI of a generated client certificate when ``security.application_uri`` is unset.
CLIENT_URI = "urn:compd:sim:client"


def server_key_path(certificate: Path) -> Path:
    """Where the server certificate's key lives: ``<name>.key.pem`` beside it."""
    return certificate.with_name(certificate.stem + ".key.pem")


def ensure_server_certificate(
    certificate: Path, uri: str, host: str | None
) -> tuple[bytes, bytes, str]:
    """The server's certificate (DER), key (PEM) and application URI; generated and saved if missing.

    The URI is the one in the certificate's subjectAltName (OPC UA requires
    the server's application URI to match it).
    """
    key_path = server_key_path(certificate)
    if not certificate.exists():
        if key_path.exists():
            raise RuntimeError(
                f"simulated OPC UA server: key {key_path} exists but certificate {certificate} "
                "does not; delete the key to have both generated"
            )
        key, cert = _generate("compd simulated PLC", uri, host, ExtendedKeyUsageOID.SERVER_AUTH)
        _save(certificate, cert, key_path, key)
    if not key_path.is_file():
        raise RuntimeError(
            f"simulated OPC UA server: certificate {certificate} has no key at {key_path}; "
            "put its key there, or delete the certificate to have both generated"
        )
    try:
        cert = load_certificate(certificate)
    except DriverError as exc:
        raise RuntimeError(f"simulated OPC UA server: {exc}") from None
    uris = _uris(cert)
    key_data = key_path.read_bytes()
    if not key_data.lstrip().startswith(b"-----"):
        key_data = cert_gen.dump_private_key_as_pem(load_der_private_key(key_data, None))  # type: ignore[arg-type]
    return cert.public_bytes(Encoding.DER), key_data, uris[0] if uris else uri


def ensure_client_certificate(certificate: Path, private_key: Path, uri: str | None) -> bytes:
    """The client certificate to trust (DER); the pair is generated and saved if both are missing."""
    if not certificate.exists() and not private_key.exists():
        key, cert = _generate("compd", uri or CLIENT_URI, None, ExtendedKeyUsageOID.CLIENT_AUTH)
        _save(certificate, cert, private_key, key)
    for path in (certificate, private_key):
        if not path.is_file():
            raise RuntimeError(
                f"simulated OPC UA server: {path} does not exist but its pair does; give both "
                "security.certificate and security.private_key, or neither to have them generated"
            )
    try:
        return bytes(load_certificate(certificate).public_bytes(Encoding.DER))
    except DriverError as exc:
        raise RuntimeError(f"simulated OPC UA server: {exc}") from None


def _uris(cert: x509.Certificate) -> list[str]:
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return []
    return [str(u) for u in san.get_values_for_type(x509.UniformResourceIdentifier)]


def _generate(
    name: str, uri: str, host: str | None, usage: x509.ObjectIdentifier
) -> tuple[rsa.RSAPrivateKey, x509.Certificate]:
    """A self-signed OPC UA application certificate: URI, this host's name and ``host`` in the SAN."""
    key = cert_gen.generate_private_key()
    names: list[x509.GeneralName] = [
        x509.UniformResourceIdentifier(uri),
        x509.DNSName(socket.gethostname()),
    ]
    if host:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    cert = cert_gen.generate_self_signed_app_certificate(
        key, name, {}, names, extended=[usage], days=CERTIFICATE_DAYS
    )
    return key, cert


def _save(cert_path: Path, cert: x509.Certificate, key_path: Path, key: rsa.RSAPrivateKey) -> None:
    """PEM where the name ends in ``.pem``, else DER: asyncua (and so the driver) reads by suffix."""
    pem = cert_path.suffix.lower() == ".pem"
    cert_path.parent.mkdir(parents=True, exist_ok=True)
    key_path.parent.mkdir(parents=True, exist_ok=True)
    cert_path.write_bytes(cert.public_bytes(Encoding.PEM if pem else Encoding.DER))
    key_format = Encoding.PEM if key_path.suffix.lower() == ".pem" else Encoding.DER
    key_path.touch(mode=0o600)
    key_path.write_bytes(key.private_bytes(key_format, PrivateFormat.PKCS8, NoEncryption()))
    log.info("generated OPC UA certificate", certificate=str(cert_path), key=str(key_path))


class OneUser(UserManager):
    """Exactly one username/password pair logs in; anything else is refused (BadUserAccessDenied)."""

    def __init__(self, username: str, password: str) -> None:
        self._username = username
        self._password = password.encode()

    def get_user(
        self, iserver: Any, username: Any = None, password: Any = None, certificate: Any = None
    ) -> User | None:
        given = password.encode() if isinstance(password, str) else bytes(password or b"")
        if username == self._username and hmac.compare_digest(given, self._password):
            return User(role=UserRole.User, name=username)
        return None


class TrustOne:
    """Certificate validator: a valid client certificate (time, URI) that is exactly the trusted one."""

    def __init__(self, trusted_der: bytes) -> None:
        self._trusted_der = trusted_der
        self._basic = CertificateValidator(
            CertificateValidatorOptions.BASIC_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
        )

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        await self._basic.validate(cert, app)
        if cert.public_bytes(Encoding.DER) != self._trusted_der:
            raise ServiceError(StatusCodes.BadCertificateUntrusted)
