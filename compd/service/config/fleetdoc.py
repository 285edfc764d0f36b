"""The config sections that connect a machine to its fleet: MQTT telemetry and roll-outs, metrics and the status page.

Each builds its runtime object as :mod:`compd.service.config.docs`'s sections
do; paho is imported only when a config has the section.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from compd.service.config.docbase import Strict


class TelemetryTlsDoc(Strict):
    """TLS to the broker: the CA that signed its certificate; a client certificate if it asks for one."""

    ca_file: str = Field(min_length=1)
    cert_file: str | None = None
    key_file: str | None = None

    @model_validator(mode="after")
    def _pair(self) -> TelemetryTlsDoc:
        if (self.cert_file is None) != (self.key_file is None):
            raise ValueError(
                "give both 'cert_file' and 'key_file' (a client certificate), or neither"
            )
        return self


#: An MQTT topic level compd writes: no wildcards, no separators, no spaces.
TopicLevel = Annotated[str, Field(pattern=r"^[A-Za-z0-9_.:-]+\Z", max_length=100)]


class TelemetryDoc(Strict):
    """MQTT telemetry (:mod:`compd.service.fleet.telemetry`): where, as whom, how often, how much to queue."""

    #: Required here only without the top-level ``machine_id``: ``ConfigDoc`` fills it in from that.
    machine_id: TopicLevel = Field(json_schema_extra={"default_is": "the top-level machine_id"})
    host: str = Field(default="localhost", min_length=1)
    port: int | None = Field(
        default=None, ge=1, le=65535, description="default: 1883, 8883 with tls"
    )
    topic_prefix: Annotated[str, Field(pattern=r"^[A-Za-z0-9_.:-]+(/[A-Za-z0-9_.:-]+)*\Z")] = (
        "compd"
    )
    every_ticks: int = Field(default=1, ge=1)
    queue_size: int = Field(default=1000, ge=1)
    qos: Literal[0, 1, 2] = 1
    #: MQTT carries the keep-alive in 16 bits: 65535 s at most.
    keepalive_s: int = Field(default=15, ge=5, le=65535)
    reconnect_min_s: int = Field(default=1, ge=1)
    reconnect_max_s: int = Field(default=30, ge=1)
    client_id: str | None = None
    username: str | None = None
    password_file: str | None = None
    tls: TelemetryTlsDoc | None = None
    #: Load models sent to ``<prefix>/<machine_id>/cmd/model_load`` (``compd model rollout``),
    #: and the roll-out's retained ``desired`` record heard at connecting (a machine back).
    #: Off unless asked: a machine takes no model from the network unless configured to.
    accept_models: bool = False

    @model_validator(mode="after")
    def _consistent(self) -> TelemetryDoc:
        if self.password_file is not None and self.username is None:
            raise ValueError("'password_file' needs 'username'")
        if self.reconnect_max_s < self.reconnect_min_s:
            raise ValueError("'reconnect_max_s' must be at least 'reconnect_min_s'")
        return self

    @property
    def broker_port(self) -> int:
        """``port``, else MQTT's: 1883, or 8883 with TLS."""
        return self.port or (1883 if self.tls is None else 8883)

    def files(self) -> dict[str, str]:
        """The files this section names, by key (``tls.ca_file``...), to check before start."""
        named = {"password_file": self.password_file}
        if self.tls is not None:
            named |= {f"tls.{k}": v for k, v in self.tls.model_dump().items()}
        return {k: v for k, v in named.items() if v is not None}


def read_secret(path: Path) -> str:
    """A password file's first line (its line ending stripped); OSError names the file, never the text."""
    return path.read_text(encoding="utf-8").rstrip("\r\n")


class HttpDoc(Strict):
    """The read-only HTTP server: Prometheus metrics at ``/metrics`` and the status page at ``/``.

    It listens on the loopback address unless told otherwise: the page shows the
    machine's state to whoever reaches the port, so opening it to a network is
    a decision made in the config (``listen: 0.0.0.0``), never a default.
    """

    enabled: bool = True
    listen: str = Field(default="127.0.0.1", min_length=1)
    #: 0: any free port (tests); the port taken is logged.
    port: int = Field(default=9780, ge=0, le=65535)
    #: Connections open at once (a browser or two and a scraper need a handful); more wait
    #: in the kernel's queue. Fewer where the open-files limit leaves too few descriptors.
    max_connections: int = Field(default=64, ge=1, le=4096)
    #: A connection with no request under way this long is closed (s): a client that sends
    #: its headers slowly, or keeps an idle connection, cannot hold a slot for longer.
    idle_timeout_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = 10.0
