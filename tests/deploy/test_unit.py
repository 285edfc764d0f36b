"""deploy/compd.service and its template compd@.service: units systemd accepts, with the options compd relies on."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from compd.cli import build_parser
from compd.files.data import load_data
from compd.service.control.socket import request_sync
from tests.installed import console_script

DEPLOY = Path(__file__).parents[2] / "deploy"
UNIT = DEPLOY / "compd.service"
TEMPLATE = DEPLOY / "compd@.service"
#: Each unit file and the name systemd sees it under (a template only as an instance).
UNITS = {"compd.service": UNIT, "compd@mill1.service": TEMPLATE}
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_systemd = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None,
    reason="systemd-analyze missing: install package systemd (.ci/install-system-packages does)",
)


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Sections of a unit file; a key may repeat (DeviceAllow=), so each maps to its values in order."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] = {}
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            current = sections.setdefault(line.strip("[]"), {})
            continue
        key, _, value = line.partition("=")
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


@pytest.fixture(scope="module", params=list(UNITS), ids=list(UNITS))
def service(request: pytest.FixtureRequest) -> dict[str, list[str]]:
    return parse_unit(UNITS[request.param].read_text())["Service"]


@pytest.fixture(params=list(UNITS), ids=list(UNITS))
def installable_unit(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at this environment's compd, as verify checks it exists."""
    compd = console_script("compd")  # this environment's, not PATH's
    if compd is None:
        pytest.skip("the compd entry point is not installed: pip install -e .")
    text = UNITS[request.param].read_text().replace("/opt/compd/venv/bin/compd", str(compd))
    path = tmp_path / request.param
    path.write_text(text)
    return path


@needs_systemd
def test_systemd_analyze_verify_accepts_the_unit(installable_unit):
    """systemd-analyze verify reports nothing: every key known, every value parsed, ExecStart runnable."""
    done = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", "--generators=no", str(installable_unit)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert installable_unit.name not in done.stderr, done.stderr


@needs_systemd
def test_sandbox_exposure_stays_low(installable_unit):
    """systemd-analyze security rates the unit's exposure at most 2.0 (measured 1.7, 'OK')."""
    done = subprocess.run(
        [SYSTEMD_ANALYZE, "security", "--offline=yes", "--threshold=20", str(installable_unit)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    name = re.escape(installable_unit.name)
    found = re.search(rf"Overall exposure level for {name}: (\d+\.\d+)", done.stdout)
    assert found and float(found[1]) <= 2.0, done.stdout[-300:]


def test_notify_and_watchdog_are_configured(service):
    """Readiness by sd_notify from the main process only, and a watchdog of 3 to 30 s."""
    assert service["Type"] == ["notify"]
    assert service["NotifyAccess"] == ["main"]
    (watchdog,) = service["WatchdogSec"]
    assert watchdog.endswith("s") and 3 <= float(watchdog[:-1]) <= 30
    assert service["Restart"] == ["on-failure"] and service["RestartSec"]


def test_execstart_is_a_command_compd_accepts(service):
    """The unit's ExecStart arguments parse as compd's own run command with a config in /etc/compd."""
    (command,) = service["ExecStart"]
    argv = shlex.split(command)
    assert argv[0].endswith("/compd")
    args = build_parser().parse_args(argv[1:])
    assert argv[1] == "run" and args.config in ("/etc/compd/compd.yaml", "/etc/compd/%i.yaml")


def test_machine_access_survives_the_sandbox(service):
    """Serial ports, CAN and the PLC network stay reachable; options that would cut them off are absent."""
    assert "dialout" in service["SupplementaryGroups"][0].split()
    assert service["DevicePolicy"] == ["closed"]
    allowed = {value.split()[0] for value in service["DeviceAllow"]}
    assert {"char-ttyS", "char-ttyUSB"} <= allowed
    families = service["RestrictAddressFamilies"][0].split()
    assert {"AF_UNIX", "AF_INET", "AF_INET6", "AF_CAN", "AF_NETLINK"} == set(families)
    for breaking in ("PrivateDevices", "PrivateNetwork", "IPAddressDeny", "PrivateUsers"):
        assert breaking not in service, f"{breaking} would cut compd off from the machine"


def test_the_service_is_confined(service):
    """Hardening options are set: no privileges, read-only system, W^X memory, system-service calls."""
    expected = {
        "ProtectSystem": "strict",
        "ProtectHome": "yes",
        "PrivateTmp": "yes",
        "NoNewPrivileges": "yes",
        "ProtectKernelTunables": "yes",
        "ProtectKernelModules": "yes",
        "ProtectKernelLogs": "yes",
        "ProtectControlGroups": "yes",
        "RestrictSUIDSGID": "yes",
        "LockPersonality": "yes",
        "MemoryDenyWriteExecute": "yes",
        "CapabilityBoundingSet": "",
    }
    for key, value in expected.items():
        assert service.get(key) == [value], key
    assert service["SystemCallFilter"][0] == "@system-service"
    assert service["StateDirectory"] in (["compd"], ["compd/%i"])
    assert service["RuntimeDirectory"] == service["StateDirectory"]


def test_reload_sends_sighup_which_compd_takes(service: dict[str, list[str]]) -> None:
    """`systemctl reload` sends SIGHUP, which compd takes (config re-read, new recording) without exiting."""
    assert service["ExecReload"] == ["/bin/kill -HUP $MAINPID"]


def test_the_template_differs_from_the_unit_only_in_its_instance_places():
    """compd@.service has compd.service's every option, the same hardening, but per-instance config and directories."""
    unit = parse_unit(UNIT.read_text())
    template = parse_unit(TEMPLATE.read_text())
    per_instance = {"Description", "ExecStart", "StateDirectory", "RuntimeDirectory", "Environment"}
    for section, options in unit.items():
        for key, values in options.items():
            if key not in per_instance:
                assert template[section].get(key) == values, f"[{section}] {key}"
    assert set(template["Service"]) == set(unit["Service"])
    service = template["Service"]
    assert service["ExecStart"][0].endswith("run --config /etc/compd/%i.yaml")
    assert service["StateDirectory"] == ["compd/%i"] and service["RuntimeDirectory"] == ["compd/%i"]
    # No XDG_STATE_HOME: a config without state.directory must fail, not share /var/lib/compd.
    assert "XDG_STATE_HOME" not in " ".join(service["Environment"])


def test_the_guides_instance_config_uses_the_templates_directories():
    """The per-instance paths deploy/README.md tells each NAME.yaml to set are the template's directories."""
    readme = (DEPLOY / "README.md").read_text()
    snippet = readme[readme.index("## Several machines on one PC") :]
    block = yaml.safe_load(re.search(r"```yaml\n(.*?)```", snippet, re.S)[1])
    service = parse_unit(TEMPLATE.read_text())["Service"]
    instance = Path(block["state"]["directory"]).name
    state = "/var/lib/" + service["StateDirectory"][0].replace("%i", instance)
    runtime = "/run/" + service["RuntimeDirectory"][0].replace("%i", instance)
    assert block["state"]["directory"] == state
    assert str(Path(block["control_socket"]).parent) == runtime


_MDWE_SCRIPT = """
import ctypes, mmap, os, sys
libc = ctypes.CDLL(None, use_errno=True)
if libc.prctl(65, 1, 0, 0, 0) != 0:  # PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN (Linux >= 6.3)
    print("unsupported", os.strerror(ctypes.get_errno()))
    sys.exit(0)
try:
    mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    print("not enforced")
    sys.exit(0)
except OSError:
    pass
from compd.cli import main
sys.exit(main(["compare", sys.argv[1], sys.argv[2], "--json"]))
"""


def test_numpy_and_scipy_run_under_memory_deny_write_execute(tmp_path):
    """With W+X mappings refused by the kernel, as MemoryDenyWriteExecute=yes does, compd compare still runs."""
    config = Path(__file__).parents[2] / "config"
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            _MDWE_SCRIPT,
            str(config / "seed000_hmc_tf.yaml"),
            str(config / "example_spectrum.csv"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    if done.stdout.startswith(("unsupported", "not enforced")):
        pytest.skip(f"kernel without PR_SET_MDWE (Linux >= 6.3): {done.stdout.strip()}")
    assert done.returncode == 0, done.stderr
    assert '"fit_percent"' in done.stdout


@pytest.fixture
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    """An abstract datagram socket standing in for systemd's notification socket."""
    name = f"compd-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(1.0)
    yield sock, "@" + name
    sock.close()


def receive(sock: socket.socket, daemon: subprocess.Popen[bytes], timeout_s: int = 60) -> bytes:
    """The next notification; fails with the daemon's output if it exits or stays silent.

    The wait is long because start-up imports numpy, scipy and pandas: seconds on a busy machine.
    """
    for _ in range(timeout_s):  # the socket's timeout is 1 s
        try:
            return sock.recv(4096)
        except TimeoutError:
            if daemon.poll() is not None:
                break
    daemon.kill()
    output, _ = daemon.communicate()
    pytest.fail(f"no notification from compd run; its output:\n{output.decode()[-3000:]}")


def daemon_config(directory: Path) -> Path:
    """The bundled simulated config with state, recordings and the socket under ``directory``."""
    doc = yaml.safe_load((Path(__file__).parents[2] / "config" / "replay.yaml").read_text())
    doc["state"]["directory"] = str(directory / "state")
    doc["recorder"] = {"enabled": True, "directory": str(directory / "records")}
    doc["control_socket"] = str(directory / "control.sock")
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture
def short_dir() -> Iterator[Path]:
    """A directory under /tmp: AF_UNIX socket paths must stay under 108 bytes, pytest's tmp_path may not."""
    directory = Path(tempfile.mkdtemp(prefix="compd-", dir="/tmp"))
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def test_compd_run_speaks_the_units_protocol(notify_socket, short_dir):
    """Run as systemd runs it, compd sends READY=1 and pings, answers status, and stops cleanly on SIGTERM."""
    sock, address = notify_socket
    directory = short_dir
    config = str(daemon_config(directory))
    # WatchdogSec=2 s: a ping each 0.5 s of real time (a quarter of it), every fifth tick at 10x.
    env = os.environ | {"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000"}
    command = [sys.executable, "-m", "compd.cli", "run", "--config", config, "--time-scale", "10"]
    daemon = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        assert receive(sock, daemon).startswith(b"READY=1\nSTATUS=compensating with ")
        assert [receive(sock, daemon) for _ in range(5)] == [b"WATCHDOG=1"] * 5
        reply = request_sync(directory / "control.sock", {"cmd": "status"})
        assert reply["ok"] and reply["model"]["name"] == "example-gated-arx-y"
        daemon.send_signal(signal.SIGTERM)
        while not receive(sock, daemon).startswith(b"STOPPING=1"):
            pass
        log, _ = daemon.communicate(timeout=60)
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.communicate()
    assert daemon.returncode == 0, log.decode()[-2000:]
    assert not (directory / "control.sock").exists()
    (recording,) = (directory / "records").glob("compd-*.csv")
    data = load_data(recording, resample=True)  # a loaded test machine may tick off the grid
    assert len(data) >= 5 and data.has("offset.Y_um")
    assert data.sample_time_s == pytest.approx(1.0, rel=0.05)


def test_the_open_files_limit_holds_every_client_cap_and_the_reserve(service):
    """LimitNOFILE is set, and holds the HTTP and control-socket caps, the fds kept for the machine and compd's own."""
    from compd.service.config.fleetdoc import HttpDoc
    from compd.service.control.peers import RESERVED_FDS
    from compd.service.control.socket import MAX_CONNECTIONS

    (value,) = service["LimitNOFILE"]
    soft = int(value.split(":")[0])
    own = 128  # the interpreter, numpy, scipy, the log, the listening sockets: ~40 measured
    assert soft >= HttpDoc().max_connections + MAX_CONNECTIONS + 1 + RESERVED_FDS + own
