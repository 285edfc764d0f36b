"""OPC UA security material for the driver: certificates, the password, refusals explained.

OPC UA ties a client's identity to its application certificate: the
application URI the client announces must be the URI in that certificate's
subjectAltName, so it is read from there. The driver's error messages turn
the server's refusal codes into the fix an operator needs. And asyncua's
DEBUG log of the requests it sends would show the password: a filter on
that logger blanks it, because compd never logs a secret. The password is
read here (:func:`read_password`) so that the simulated PLC's server checks
the very password the driver sends.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

from asyncua import ua
from asyncua.ua.status_codes import StatusCodes
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding

from compd.drivers.base import HostProblem
from compd.drivers.opcua.settings import OpcUaSettings
from compd.errors import DriverError, DriverProtocolError
from compd.files.yamlplace import resolve_path


class _RedactPasswords(logging.Filter):
    """Blank the password in asyncua's DEBUG dump of every request it sends.

    asyncua logs ``Sending: <request>`` with the whole ActivateSessionRequest,
    whose UserNameIdentityToken holds the password (in clear when the server's
    token policy leaves encryption to the secure channel). compd never logs a
    secret, so the record is rewritten before any handler sees it.
    """

    _PASSWORD = re.compile(r"Password=.*?(?=, EncryptionAlgorithm=)", re.DOTALL)

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if "Password=" in message:
            record.msg, record.args = self._PASSWORD.sub("Password=<redacted>", message), ()
        return True


logging.getLogger("asyncua.client.ua_client.UASocketProtocol").addFilter(_RedactPasswords())

#: Status codes that mean the server refused who we are, with the fix to name.
REFUSALS: dict[int, str] = {
    StatusCodes.BadUserAccessDenied: "refused the user: wrong username or password",
    StatusCodes.BadIdentityTokenInvalid: "refused the user: wrong username or password",
    StatusCodes.BadIdentityTokenRejected: "does not accept username logins on this endpoint",
    StatusCodes.BadCertificateUntrusted: (
        "does not trust the client certificate: add it to the server's trusted certificates"
    ),
    StatusCodes.BadSecurityChecksFailed: (
        "refused the secure channel: client certificate not trusted or not valid"
    ),
    StatusCodes.BadCertificateUriInvalid: (
        "refused the client certificate: its URI does not match application_uri"
    ),
    StatusCodes.BadCertificateTimeInvalid: "refused the client certificate: expired or not yet valid",
    StatusCodes.BadCertificateUseNotAllowed: (
        "refused the client certificate: wrong key usage for a client"
    ),
    StatusCodes.BadSecurityPolicyRejected: "does not offer this security policy",
}


def settings_file(name: str, base_dir: Path) -> Path:
    """A file the settings name (relative to ``base_dir``, the config's folder); it must exist."""
    path = resolve_path(name, base_dir)
    if not path.is_file():
        raise DriverError(f"OPC UA driver: file {path} does not exist")
    return path


def check_files(settings: OpcUaSettings, base_dir: Path) -> HostProblem | None:
    """The first certificate, key or password file the settings name that cannot be read."""
    files: list[tuple[tuple[str, ...], str | None, str]] = [
        (("password_file",), settings.password_file, "the file holding the user's password")
    ]
    if (security := settings.security) is not None:
        files = [
            (("security", "certificate"), security.certificate, "compd's client certificate"),
            (("security", "private_key"), security.private_key, "the client certificate's key"),
            (
                ("security", "server_certificate"),
                security.server_certificate,
                "the server's certificate, exported from the controller",
            ),
            *files,
        ]
    for keys, name, what in files:
        if name is None:
            continue
        path = resolve_path(name, base_dir)
        try:
            with path.open("rb"):
                pass
        except OSError as exc:
            return HostProblem(
                keys,
                f"cannot read {path} ({exc.strerror or type(exc).__name__}), so the driver "
                "could never connect",
                f"Put {what} there, or give its path (relative paths start at {base_dir}); "
                "deploy/README.md shows how to make the certificates",
            )
    return None


def read_password(settings: OpcUaSettings, base_dir: Path) -> str:
    """The password from ``password_file`` or ``password_env``; ``""`` when neither is set.

    Public so that the simulated PLC accepts exactly what the driver sends.
    DriverError names the file or variable, never the password's text.
    """
    if settings.password_file:
        path = settings_file(settings.password_file, base_dir)
        try:
            return path.read_text(encoding="utf-8").rstrip("\r\n")
        except (OSError, UnicodeDecodeError) as exc:  # the message names the file, not its text
            raise DriverError(
                f"OPC UA driver: cannot read password_file {path} ({type(exc).__name__})"
            ) from None
    if settings.password_env:
        value = os.environ.get(settings.password_env)
        if value is None:
            raise DriverError(
                f"OPC UA driver: environment variable {settings.password_env} "
                "(password_env) is not set"
            )
        return value
    return ""


def load_certificate(path: Path) -> x509.Certificate:
    data = path.read_bytes()
    try:
        if data.lstrip().startswith(b"-----"):
            return x509.load_pem_x509_certificate(data)
        return x509.load_der_x509_certificate(data)
    except ValueError as exc:
        raise DriverError(f"OPC UA driver: {path} is not a PEM or DER certificate") from exc


def certificate_der(path: Path) -> bytes:
    return load_certificate(path).public_bytes(Encoding.DER)


def certificate_uri(path: Path) -> str:
    """The application URI in a certificate's subjectAltName (OPC UA requires it to match)."""
    cert = load_certificate(path)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound as exc:
        raise DriverError(f"OPC UA client certificate {path} has no subjectAltName URI") from exc
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    if not uris:
        raise DriverError(
            f"OPC UA client certificate {path} has no URI; set security.application_uri"
        )
    return str(uris[0])


def check_endpoints(
    url: str,
    endpoints: list[ua.EndpointDescription],
    trusted_der: bytes,
    policy_uri: str,
    mode: ua.MessageSecurityMode,
) -> None:
    """Refuse a server whose endpoints present another certificate, or lack the policy and mode.

    ``ServerCertificate`` may hold a chain, the server's own certificate first.
    """
    presented = {bytes(e.ServerCertificate) for e in endpoints if e.ServerCertificate}
    if presented and not any(p.startswith(trusted_der) for p in presented):
        raise DriverProtocolError(
            f"OPC UA server {url} presented a certificate that is not "
            "security.server_certificate: server not trusted, refusing to connect "
            "(if it is the right machine, put its certificate in security.server_certificate)"
        )
    offered = {(e.SecurityPolicyUri, e.SecurityMode) for e in endpoints}
    if (policy_uri, mode) not in offered:
        names = sorted(f"{_policy_name(u)}/{m.name}" for u, m in offered)
        raise DriverProtocolError(
            f"OPC UA server {url} does not offer {_policy_name(policy_uri)}/{mode.name}; "
            f"it offers {', '.join(names)}: set security.policy and security.mode to one it offers"
        )


def _policy_name(uri: str) -> str:
    """``Basic256Sha256`` for ``http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256``."""
    return uri.rsplit("#", 1)[-1]
