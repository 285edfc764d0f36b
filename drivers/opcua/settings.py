"""The OPC UA driver's settings: the server, the secure channel, the user.

Security is on unless switched off in words: ``security`` is required, with
``SignAndEncrypt`` and ``Basic256Sha256`` unless it says otherwise;
``security: none`` must be written out and is refused together with a
password, which would otherwise cross the wire in clear.
"""

from __future__ import annotations

from typing import Literal
from urllib.parse import urlsplit

from asyncua.crypto import security_policies
from pydantic import BaseModel, ConfigDict, Field, model_validator

from compd.drivers.endpoints import Endpoint, tcp_endpoint

#: Security policies offered in ``security.policy``, by their OPC UA names.
POLICIES: dict[str, type[security_policies.SecurityPolicy]] = {
    "Basic256Sha256": security_policies.SecurityPolicyBasic256Sha256,
    "Aes256_Sha256_RsaPss": security_policies.SecurityPolicyAes256Sha256RsaPss,
}
#: OPC UA's registered TCP port, where a URL names none.
DEFAULT_PORT = 4840
#: The fix named when ``security`` is missing, or ``none`` with a password.
_SECURITY_FIX = (
    "give security.certificate, security.private_key and security.server_certificate "
    "(mode SignAndEncrypt by default), or write 'security: none' for a server without "
    "security, which cannot be combined with a password"
)


class OpcUaSecurity(BaseModel):
    """``settings.security``: the secure channel and the client's own certificate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    policy: Literal["Basic256Sha256", "Aes256_Sha256_RsaPss"] = "Basic256Sha256"
    mode: Literal["SignAndEncrypt", "Sign"] = "SignAndEncrypt"
    certificate: str = Field(min_length=1, description="client certificate, PEM or DER")
    private_key: str = Field(min_length=1, description="client private key, PEM or DER")
    server_certificate: str = Field(
        min_length=1, description="the one server certificate trusted, PEM or DER"
    )
    application_uri: str | None = Field(
        default=None, description="client application URI; default: the certificate's URI"
    )


class OpcUaSettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: opcua`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    url: str = Field(pattern=r"^opc\.tcp://[^@/]+(/.*)?$", description="opc.tcp://host:port/path")
    #: Required: a block, or ``none`` written out (stored as None).
    security: OpcUaSecurity | None
    username: str | None = None
    password_file: str | None = Field(default=None, description="file holding the password")
    password_env: str | None = Field(default=None, description="environment variable")
    request_timeout_s: float = Field(default=2.0, gt=0, description="per OPC UA request")

    def endpoint(self) -> Endpoint:
        """The server's host and port (4840 unless the URL says otherwise); the path names no other server."""
        url = urlsplit(self.url)
        try:
            port = url.port or DEFAULT_PORT
        except ValueError:  # not a number: connecting fails; compare the text meanwhile
            return ("opc.tcp", url.netloc.lower())
        return tcp_endpoint("opc.tcp", url.hostname or "", port)

    @model_validator(mode="before")
    @classmethod
    def _security_is_explicit(cls, data: object) -> object:
        """No security only when written out: ``security: none`` (an absent block is an error)."""
        if not isinstance(data, dict):
            return data
        if data.get("security") is None:
            raise ValueError(f"'security' is missing: {_SECURITY_FIX}")
        if data["security"] == "none":
            return {**data, "security": None}
        return data

    @model_validator(mode="after")
    def _one_password_source(self) -> OpcUaSettings:
        sources = [s for s in (self.password_file, self.password_env) if s]
        if len(sources) > 1:
            raise ValueError("give password_file or password_env, not both")
        if sources and not self.username:
            raise ValueError("a password needs a username")
        if sources and self.security is None:
            raise ValueError(
                "'security: none' with a password would send the password in clear; "
                + _SECURITY_FIX
            )
        return self
