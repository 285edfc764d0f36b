"""A real mosquitto broker on a free port, and a paho subscriber that keeps what it hears.

Shared by the telemetry tests, the fleet test and ``benchmarks/bench_telemetry.py``.
The broker is a child process with its own config in a temporary folder
(never the system's service); a test skips, naming
``.ci/install-system-packages``, where mosquitto is not installed.
"""

from __future__ import annotations

import getpass
import json
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import yaml
from paho.mqtt.enums import CallbackAPIVersion

from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config
from tests.ports import free_port

#: Real-time bound of the waits below: generous, a busy CI machine must not fail them.
WAIT_S = 90.0  # a failure guard only: three daemons start on a loaded 2-core machine


def mosquitto_binary() -> str | None:
    """The mosquitto executable (Debian puts it in /usr/sbin, often not on a user's PATH)."""
    found = shutil.which("mosquitto") or shutil.which("mosquitto", path="/usr/sbin:/usr/local/sbin")
    return found


class Mosquitto:
    """``mosquitto -c <folder>/mosquitto.conf`` on 127.0.0.1:``port``; :meth:`start`, :meth:`stop`.

    ``extra``: more lines for its config (another listener with TLS and a
    password file; ``per_listener_settings`` then). Restartable on the same
    port (a broker pulled mid-shift and put back).
    """

    def __init__(self, folder: Path, *, port: int | None = None, extra: Iterable[str] = ()) -> None:
        extra = list(extra)
        binary = mosquitto_binary()
        if binary is None:
            raise RuntimeError("mosquitto is not installed (.ci/install-system-packages)")
        self.binary = binary
        self.folder = folder
        self.port = port or free_port()
        self.log = folder / "mosquitto.log"
        self.conf = folder / "mosquitto.conf"
        lines = [
            *(["per_listener_settings true"] if extra else []),
            f"listener {self.port} 127.0.0.1",
            "allow_anonymous true",
            "persistence false",
            # As root, mosquitto would drop to user 'mosquitto', who cannot read the test's files.
            f"user {getpass.getuser()}",
            "log_dest stderr",
            "log_type error",
            "log_type warning",
            "log_type notice",
            "max_queued_messages 100000",
        ]
        self.conf.write_text("\n".join([*lines, *extra]) + "\n")
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> Mosquitto:
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(
                [self.binary, "-c", str(self.conf)], stdout=log, stderr=subprocess.STDOUT
            )
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"mosquitto exited: {self.log.read_text()[-2000:]}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return self
            except OSError:
                time.sleep(0.02)
        raise RuntimeError(f"mosquitto did not listen on {self.port}")

    def stop(self) -> None:
        """Kill the broker (SIGKILL: pulled, not shut down politely) and reap it."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.process = None


@dataclass
class Heard:
    topic: str
    payload: dict[str, Any]
    retained: bool
    received_unix_s: float


@dataclass
class Subscriber:
    """A paho client subscribed to ``topic`` (``#``-style), keeping every JSON message it hears."""

    port: int
    topic: str = "#"
    messages: list[Heard] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"sub-{id(self)}")
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *a: self._subscribed.set()
        self.client.on_message = self._on_message

    def __enter__(self) -> Subscriber:
        self.client.connect("127.0.0.1", self.port, 30)
        self.client.loop_start()
        if not self._subscribed.wait(WAIT_S):
            raise RuntimeError("the subscriber did not subscribe")
        return self

    def __exit__(self, *exc: object) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_connect(self, client: mqtt.Client, *args: Any) -> None:
        client.subscribe(self.topic, qos=1)

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        heard = Heard(message.topic, json.loads(message.payload), message.retain, time.time())
        with self._lock:
            self.messages.append(heard)

    def of(self, kind: str, machine: str | None = None) -> list[dict[str, Any]]:
        """The payloads of ``kind`` (``birth``, ``status``...), of one machine or all."""
        with self._lock:
            return [
                m.payload
                for m in self.messages
                if m.payload.get("kind") == kind
                and (machine is None or m.payload.get("machine_id") == machine)
            ]

    def wait_for(self, predicate: Callable[[Subscriber], bool], what: str) -> None:
        """Wait (real time, bounded by WAIT_S) until ``predicate(self)``; else fail naming ``what``."""
        deadline = time.monotonic() + WAIT_S
        while not predicate(self):
            if time.monotonic() > deadline:
                raise AssertionError(f"never heard {what}; heard {len(self.messages)} messages")
            time.sleep(0.01)


@dataclass(frozen=True)
class Pki:
    """A CA, a broker certificate for 127.0.0.1 and a client certificate, as PEM files in one folder."""

    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path


def make_pki(folder: Path) -> Pki:
    """Generate the CA and the two certificates it signs (RSA 2048, a day's validity)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.UTC)

    def name(common: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common)])

    def key() -> rsa.RSAPrivateKey:
        return rsa.generate_private_key(public_exponent=65537, key_size=2048)

    def save(path: Path, cert: x509.Certificate, private: rsa.RSAPrivateKey) -> None:
        path.with_suffix(".crt").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        path.with_suffix(".key").write_bytes(
            private.private_bytes(
                serialization.Encoding.PEM,
                serialization.PrivateFormat.TraditionalOpenSSL,
                serialization.NoEncryption(),
            )
        )

    def builder(subject: str, issuer: str, public: Any) -> x509.CertificateBuilder:
        return (
            x509.CertificateBuilder()
            .subject_name(name(subject))
            .issuer_name(name(issuer))
            .public_key(public)
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
        )

    ca_key = key()
    ca = (
        builder("compd test CA", "compd test CA", ca_key.public_key())
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    save(folder / "ca", ca, ca_key)
    server_key = key()
    server = (
        builder("127.0.0.1", "compd test CA", server_key.public_key())
        .add_extension(
            x509.SubjectAlternativeName(
                [x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.DNSName("localhost")]
            ),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())
    )
    save(folder / "server", server, server_key)
    client_key = key()
    client = builder("compd", "compd test CA", client_key.public_key()).sign(
        ca_key, hashes.SHA256()
    )
    save(folder / "client", client, client_key)
    return Pki(
        folder / "ca.crt",
        folder / "server.crt",
        folder / "server.key",
        folder / "client.crt",
        folder / "client.key",
    )


#: The bundled simulated machine and its model, which the telemetry and fleet tests run.
SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))
MODEL = resolve_path("bundled:simulated_model.yaml", Path("."))


def machine_config(
    directory: Path,
    *,
    telemetry: dict[str, Any] | None,
    simulation: dict[str, Any] | None = None,
    name: str = "compd.yaml",
) -> Config:
    """The bundled simulated machine on a free port, its files under ``directory``, with ``telemetry``."""
    directory.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = yaml.safe_load(SIMULATED.read_text())
    doc["model"] = str(MODEL)
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state")}
    doc["recorder"] = {"enabled": False}
    doc["control_socket"] = str(directory / "c.sock")
    doc["simulation"] = simulation or {"scenario": "production", "hours": 1, "seed": 3}
    if telemetry is not None:
        doc["telemetry"] = telemetry
    path = directory / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)
