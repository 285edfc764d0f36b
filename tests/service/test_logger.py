"""A config without outputs is a data logger: checked as any config, it reads and records, and writes nothing."""

from __future__ import annotations

import asyncio
import csv
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.cli import main
from compd.errors import ConfigFileError
from compd.files.data import load_data
from compd.files.yamlplace import resolve_path
from compd.service.config.loading import Config, load_config
from compd.service.control.modelload import slot_from_bytes
from compd.sim.plc.run import run_simulation

from ..drivers.modbus_server import free_port
from .daemon_setup import short_socket

RECORD = resolve_path("bundled:record.yaml", Path("."))
SIMULATED = resolve_path("bundled:simulated.yaml", Path("."))


def machine_config(directory: Path, bundled: Path, **changes: Any) -> Config:
    """A bundled simulated-machine config on a free port, its state under ``directory``, 1 h long."""
    doc = yaml.safe_load(bundled.read_text())
    doc["drivers"]["plc"]["settings"]["port"] = free_port()
    doc["state"] = {"directory": str(directory / "state")}
    doc["control_socket"] = str(short_socket())
    doc["simulation"] |= {"hours": 1}
    if changes.pop("no_model", False):
        del doc["model"]
    elif "model" in doc:
        doc["model"] = str(bundled.parent / doc["model"])
    doc |= changes
    path = directory / "compd.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_config(path)


def test_outputs_empty_is_a_logger_that_check_config_accepts(tmp_path, capsys):
    """`outputs: {}` and no model pass check-config, which says the config only records."""
    config = machine_config(tmp_path, SIMULATED, no_model=True, outputs={}, status=None)
    assert config.logger and config.model_path is None and not config.doc.outputs
    assert main(["check-config", str(config.path)]) == 0
    assert "a data logger at 1 s: no outputs, no model" in capsys.readouterr().out


def test_outputs_without_a_model_are_refused_naming_the_fix(tmp_path):
    """Outputs need a model: the error names the outputs, the line and both ways out."""
    with pytest.raises(ConfigFileError) as info:
        machine_config(tmp_path, SIMULATED, no_model=True)
    message = str(info.value)
    assert "(outputs): outputs ['Z'] need a model to compute their offsets" in message
    assert "Name the model file" in message and "remove 'outputs'" in message
    assert "compd record" in message and "at least 1 item" not in message


def test_a_logger_records_every_tick_and_writes_nothing_to_the_plc(tmp_path):
    """On the simulated PLC: N ticks recorded with the probe's column, no register written, status works."""
    config = machine_config(tmp_path, RECORD)
    statuses: list[dict[str, Any]] = []
    result = asyncio.run(
        run_simulation(
            config,
            duration_s=1800,
            on_tick=lambda service, machine, record: statuses.append(service.status()),
        )
    )
    ticks = result.timing.ticks
    assert ticks == 181  # 0..1800 s every 10 s
    plc = result.machine.plc
    assert plc.writes == 0 and plc.status_word is None and plc.heartbeat is None
    status = statuses[-1]
    assert status["model"] is None and status["offsets_um"] == {}
    assert status["counters"]["ticks"] == ticks and status["inputs"]["disp_z_um"]["health"] == "ok"
    files = sorted(config.recorder_dir.glob("compd-*.csv"))
    assert len(files) == 1
    with files[0].open() as f:
        rows = list(
            csv.DictReader(line for line in f if not line.startswith("#"))
        )  # metadata lines
    assert len(rows) == ticks and "disp_z_um" in rows[0] and "health.disp_z_um" in rows[0]
    data = load_data(files[0])
    assert data.sample_time_s == 10.0 and len(data) == ticks and "disp_z_um" in data.columns


def test_recording_a_compensating_config_writes_nothing(tmp_path):
    """compd record's view of a config with outputs and a status word: its signals only, no write."""
    config = machine_config(tmp_path, SIMULATED).recording(tmp_path / "rec", max_file_bytes=10**6)
    assert config.logger and config.doc.status is None and not config.doc.outputs
    result = asyncio.run(run_simulation(config, duration_s=120))
    assert result.timing.ticks == 121 and result.machine.plc.writes == 0
    assert len(list((tmp_path / "rec").glob("compd-*.csv"))) == 1


def test_a_logger_has_no_model_to_load(tmp_path):
    """`compd model load` into a logger is refused: add outputs and a model instead."""
    config = machine_config(tmp_path, RECORD)
    model = resolve_path("bundled:simulated_model.yaml", Path("."))
    with pytest.raises(ConfigFileError, match=r"a data logger .* no model to switch"):
        slot_from_bytes(config, model.read_bytes(), model, 0.0)


def test_outputs_empty_with_a_model_runs_it_and_writes_nothing(tmp_path, capsys):
    """`outputs: {}` beside a model: check-config passes; the model runs and is recorded, nothing is written."""
    config = machine_config(tmp_path, SIMULATED, outputs={}, status=None)
    assert not config.logger
    assert main(["check-config", str(config.path)]) == 0
    assert "outputs disp_z_um" in capsys.readouterr().out
    records = []
    result = asyncio.run(
        run_simulation(
            config,
            duration_s=600,
            on_tick=lambda service, machine, record: records.append(record),
        )
    )
    assert result.timing.ticks == 601 and result.machine.plc.writes == 0
    assert records[-1].offsets_um == {} and abs(records[-1].model_outputs["disp_z_um"]) < 1e3


def test_the_bundled_logger_config_checks(capsys):
    """`compd check-config bundled:record.yaml`, the modelling loop's first command, passes."""
    assert main(["check-config", "bundled:record.yaml"]) == 0
    out = capsys.readouterr().out
    assert "a data logger at 10 s" in out and "disp_z_um" in out and "calibration, 24 h" in out


def test_a_logger_publishes_telemetry_and_serves_its_page_without_a_model(tmp_path):
    """A data logger with telemetry and the HTTP server: birth and statuses name no model; the page says so."""
    import json
    import subprocess
    import sys
    import time
    import urllib.request

    from tests.mosquitto import Mosquitto, Subscriber, mosquitto_binary

    if mosquitto_binary() is None:
        pytest.skip("mosquitto is not installed (.ci/install-system-packages)")
    broker = Mosquitto(tmp_path).start()
    http_port = free_port()
    config = machine_config(
        tmp_path,
        RECORD,
        machine_id="logger-1",
        telemetry={"host": "127.0.0.1", "port": broker.port, "every_ticks": 1},
        http={"port": http_port},
    )
    command = [sys.executable, "-m", "compd.cli", "run", "--config", str(config.path)]
    command += ["--time-scale", "10", "--duration-s", "150", "--log-format", "json"]
    pages: dict[str, Any] = {}
    try:
        with Subscriber(broker.port, "compd/logger-1/#") as heard:
            daemon = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            deadline = time.monotonic() + 60
            while "metrics" not in pages and time.monotonic() < deadline and daemon.poll() is None:
                try:
                    base = f"http://127.0.0.1:{http_port}/"
                    with urllib.request.urlopen(base + "page.json", timeout=5) as answer:
                        page = json.load(answer)
                    if page["status"]["word"] is None:
                        raise OSError("no tick yet")
                    pages["page"] = page
                    with urllib.request.urlopen(base + "metrics", timeout=5) as answer:
                        pages["metrics"] = answer.read().decode()
                except OSError:
                    time.sleep(0.2)
            _, err = daemon.communicate(timeout=120)
            assert daemon.returncode == 0, err.decode()[-3000:]
            messages = list(heard.messages)
    finally:
        broker.stop()
    assert pages["page"]["model"] is None
    assert "compd_ticks" in pages["metrics"] and "compd_model_info" not in pages["metrics"]
    births = [m for m in messages if m.topic.endswith("/birth")]
    statuses = [m for m in messages if m.topic.endswith("/status")]
    assert births and births[0].payload["model"] is None
    assert statuses and all(m.payload["model"] is None for m in statuses)
