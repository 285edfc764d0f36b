"""The MQTT connection a daemon and the roll-out client share: where, who, TLS; the topic names.

One paho-mqtt 2.x client per use, built from :class:`Broker` by
:func:`mqtt_client`: telemetry (:mod:`compd.service.fleet.telemetry`) and the
fleet roll-out (:mod:`compd.cli.rollout`) connect the same way, so a broker's
users, TLS files and backoff are configured once (the ``telemetry:`` section).

They speak MQTT 5 (mosquitto 1.6 and later, and the other current brokers):
its CONNECT carries the client's Maximum Packet Size
(:func:`connect_properties`), which the broker must respect: a larger message
is dropped there, never sent to (and buffered by) the daemon.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from compd.files.yamlplace import resolve_path
from compd.service.config.fleetdoc import TelemetryDoc, read_secret


@dataclass(frozen=True)
class Broker:
    """Where and how to connect: host, port, TLS files, the user and the password (already read)."""

    host: str
    port: int
    client_id: str
    keepalive_s: int = 15
    reconnect_min_s: int = 1
    reconnect_max_s: int = 30
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None


@dataclass(frozen=True)
class Topics:
    """``<prefix>/<machine_id>/{birth,status,event,death}``."""

    prefix: str
    machine_id: str

    def of(self, kind: str) -> str:
        return f"{self.prefix}/{self.machine_id}/{kind}"


def mqtt_client(broker: Broker) -> mqtt.Client:
    """A paho client (MQTT 5) for ``broker``: its id, user and password, TLS files, reconnect backoff."""
    client = mqtt.Client(
        CallbackAPIVersion.VERSION2, client_id=broker.client_id, protocol=MQTTProtocolVersion.MQTTv5
    )
    client.reconnect_delay_set(broker.reconnect_min_s, broker.reconnect_max_s)
    if broker.username is not None:
        client.username_pw_set(broker.username, broker.password)
    if broker.ca_file is not None:
        client.tls_set(
            ca_certs=str(broker.ca_file),
            certfile=None if broker.cert_file is None else str(broker.cert_file),
            keyfile=None if broker.key_file is None else str(broker.key_file),
        )
    return client


def connect_properties(max_packet_bytes: int) -> Properties:
    """CONNECT's properties: the largest packet this client takes (MQTT 5's Maximum Packet Size).

    The broker drops a message that would make a larger packet for this client
    (MQTT 5.0, 3.1.2.11.4) instead of sending it.
    """
    properties = Properties(PacketTypes.CONNECT)  # type: ignore[no-untyped-call]
    properties.MaximumPacketSize = max_packet_bytes
    return properties


def broker(doc: TelemetryDoc, base_dir: Path, client_id: str) -> Broker:
    """Where and as whom to connect (the password file read now); also the roll-out's."""

    def path(name: str | None) -> Path | None:
        return None if name is None else resolve_path(name, base_dir)

    password_path = path(doc.password_file)
    tls = doc.tls
    return Broker(
        host=doc.host,
        port=doc.broker_port,
        client_id=client_id,
        keepalive_s=doc.keepalive_s,
        reconnect_min_s=doc.reconnect_min_s,
        reconnect_max_s=doc.reconnect_max_s,
        username=doc.username,
        password=None if password_path is None else read_secret(password_path),
        ca_file=None if tls is None else path(tls.ca_file),
        cert_file=None if tls is None else path(tls.cert_file),
        key_file=None if tls is None else path(tls.key_file),
    )
