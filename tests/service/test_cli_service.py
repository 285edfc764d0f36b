"""The daemon's commands: run, check-config, status, model load."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from compd.cli import daemon as cli_daemon
from compd.cli import main
from compd.cli.starthint import start_hint
from compd.service.control.socket import ControlServer, request_sync
from compd.service.store.state import installed_model

from .daemon_setup import short_socket, write_config

RUN = [sys.executable, "-m", "compd.cli", "run", "--config"]


def test_check_config_accepts_the_bundled_simulated_config(capsys):
    """check-config on bundled:simulated.yaml prints ok and the wiring."""
    assert main(["check-config", "bundled:simulated.yaml"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("ok: ") and "axis Z: -1 x disp_z_um -> plc:holding:100:int32" in out


def test_check_config_error_exits_2_naming_the_place(tmp_path, capsys):
    """A config error ends check-config with exit status 2 and the file, line and place."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema: compd.config/1\nmodel: m.yaml\nperiod_s: fast\n")
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: line 3 (period_s): Input should be a valid number" in err


@pytest.mark.parametrize(
    ("written", "typo", "place"),
    [
        ("  seed: 1\n", "  seed: 1\n  variant: longnose\n", "simulation.variant"),
        (
            "  heartbeat_timeout_s: 5     # the PLC counts a heartbeat not renewed this long\n",
            "  heartbeat_timeout_s: 5\n  faults:\n"
            "    - {kind: nan, signal: T_spindl_degC, at_s: 7200, duration_s: 120}\n",
            "simulation.faults.0.signal",
        ),
    ],
)
def test_check_config_error_in_simulation_is_an_error_not_ok(
    tmp_path, capsys, written, typo, place
):
    """An error in the simulation section prints no 'ok', only the error (file, place, fix), exit 2."""
    bundled = Path(cli_daemon.__file__).parents[2] / "config"
    text = (bundled / "simulated.yaml").read_text()
    assert written in text
    bad = tmp_path / "simulated.yaml"
    bad.write_text(text.replace(written, typo))
    (tmp_path / "simulated_model.yaml").write_bytes((bundled / "simulated_model.yaml").read_bytes())
    assert main(["check-config", str(bad)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert f"{bad}: {place}: unknown" in captured.err and "Use one of" in captured.err


def test_run_stops_after_duration_and_saves_state(tmp_path):
    """compd run --time-scale --duration-s exits 0 after the clock time, JSON logs on stderr, state saved."""
    config = write_config(
        tmp_path, {"control_socket": str(short_socket()), "recorder": {"enabled": True}}
    )
    done = subprocess.run(
        [
            *RUN,
            str(config.path),
            "--time-scale",
            "200",
            "--duration-s",
            "60",
            "--log-format",
            "json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "", "logs go to stderr, never stdout"
    events = [json.loads(line)["event"] for line in done.stderr.splitlines()]
    assert events[0] == "model" and events[-1] == "stopped"
    assert (config.state_dir / "state.json").is_file()
    assert list((config.state_dir / "records").glob("compd-*.csv"))


def test_model_load_without_a_daemon_installs_for_the_next_start(tmp_path, capsys):
    """model load validates and installs the model even when no daemon runs, and says so."""
    config = write_config(tmp_path, {"control_socket": str(short_socket())})
    copy = tmp_path / "copy.yaml"  # other bytes than the config's own model, which is not copied
    copy.write_text(config.model_path.read_text() + "# a copy\n")
    assert main(["model", "load", str(copy), "--config", str(config.path)]) == 0
    captured = capsys.readouterr()
    assert "installed example-gated-arx-y" in captured.out
    assert "it will start with this model" in captured.err
    assert installed_model(config.state_dir) is not None


def test_model_load_that_a_live_daemon_does_not_answer_fails_and_installs_nothing(
    tmp_path, capsys, monkeypatch
):
    """A daemon that runs but does not answer the load: exit 2 saying so, and current-model stays as it was."""
    config = write_config(tmp_path, {"control_socket": str(short_socket())})
    monkeypatch.setattr(cli_daemon, "LOAD_TIMEOUT_S", 0.0)  # the client waits 10 s, not 40

    async def stuck(message: dict[str, Any]) -> dict[str, Any]:
        await asyncio.sleep(3600)  # a daemon whose loop is held up, or whose check hangs
        return {}

    async def live_daemon(started: threading.Event, stop: asyncio.Event) -> None:
        async with ControlServer(config.control_socket, {"load": stuck}):
            started.set()
            await stop.wait()

    loop = asyncio.new_event_loop()
    started, stop = threading.Event(), asyncio.Event()
    thread = threading.Thread(target=loop.run_until_complete, args=(live_daemon(started, stop),))
    thread.start()
    try:
        assert started.wait(60)
        argv = ["model", "load", str(config.model_path), "--config", str(config.path)]
        assert main(argv) == 2
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(60)
        loop.close()
    err = capsys.readouterr().err
    assert "was not loaded and nothing was installed" in err and "no reply from compd" in err
    assert installed_model(config.state_dir) is None


def test_model_load_refuses_a_bad_model(tmp_path, capsys):
    """A model that does not compile is refused with exit 2 and nothing is installed."""
    config = write_config(tmp_path, {"control_socket": str(short_socket())})
    bad = tmp_path / "bad.yaml"
    bad.write_text(config.model_path.read_text().replace("-0.998889505944279", "-1.5"))
    assert main(["model", "load", str(bad), "--config", str(config.path)]) == 2
    assert "unstable" in capsys.readouterr().err
    assert installed_model(config.state_dir) is None


def test_model_load_of_a_5000_digit_gain_names_the_file_and_place(tmp_path, capsys):
    """A model file holding an integer of 5,000 digits: exit 2, the file and the place, no traceback."""
    config = write_config(tmp_path, {"control_socket": str(short_socket())})
    text = config.model_path.read_text()
    assert "gain: 1.0" in text
    bad = tmp_path / "huge.yaml"
    bad.write_text(text.replace("gain: 1.0", "gain: " + "9" * 5000, 1))
    assert main(["model", "load", str(bad), "--config", str(config.path)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: line " in err and ".gain): " in err and "an integer of 5000 digits" in err
    assert installed_model(config.state_dir) is None


def test_status_without_a_daemon(tmp_path, capsys):
    """status with no daemon running exits 2 asking whether compd runs, and how to start this config's."""
    config = write_config(tmp_path, {"control_socket": str(short_socket())})
    assert main(["status", "--config", str(config.path)]) == 2
    err = capsys.readouterr().err
    assert "is compd running?" in err and f"start it with: compd run --config {config.path}" in err
    assert "systemctl" not in err, "no unit runs a config outside /etc/compd"


def test_start_hint_names_the_unit_only_where_it_is_installed(tmp_path):
    """systemctl start compd / compd@NAME where the unit file is installed, else compd run --config."""
    units = tmp_path / "system"
    units.mkdir()
    default, line2 = Path("/etc/compd/compd.yaml"), Path("/etc/compd/line2.yaml")
    assert start_hint(default, (units,)) == f"start it with: compd run --config {default}"
    (units / "compd@.service").write_text("[Service]\n")
    assert start_hint(line2, (units,)) == "start it with: systemctl start compd@line2"
    assert start_hint(default, (units,)) == "start it with: systemctl start compd@compd"
    (units / "compd.service").write_text("[Service]\n")
    assert start_hint(default, (units,)) == "start it with: systemctl start compd"
    elsewhere = tmp_path / "compd.yaml"
    assert start_hint(elsewhere, (units,)) == f"start it with: compd run --config {elsewhere}"


def start_daemon(config, time_scale: float) -> subprocess.Popen[str]:
    """``compd run`` on ``config`` at ``time_scale``, once its control socket is there."""
    daemon = subprocess.Popen(
        [*RUN, str(config.path), "--time-scale", str(time_scale), "--log-format", "json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not config.control_socket.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return daemon


def ticked(config, ticks: int) -> None:
    """Until the daemon has ticked ``ticks`` times (a busy host starts it slowly; 60 s hang guard)."""
    deadline = time.monotonic() + 60
    while request_sync(config.control_socket, {"cmd": "status"})["counters"]["ticks"] < ticks:
        assert time.monotonic() < deadline, f"fewer than {ticks} ticks in 60 s"
        time.sleep(0.05)


def test_status_under_time_scale_and_loading_the_running_model(tmp_path, capsys):
    """At --time-scale 100: units, the last tick's age, no future times; loading the running model: a no-op."""
    config = write_config(tmp_path, {"control_socket": str(short_socket()), "blend_s": 5})
    daemon = start_daemon(config, time_scale=100)
    try:
        ticked(config, 100)  # 100 clock seconds: the scaled clock is well ahead of the wall's
        assert main(["status", "--config", str(config.path), "--json"]) == 0
        reply = json.loads(capsys.readouterr().out)
        now = datetime.now(UTC) + timedelta(seconds=1)  # stamps are cut to whole seconds
        for stamp in (reply["last_tick"], reply["started"], reply["model"]["loaded"]):
            assert datetime.fromisoformat(stamp) <= now, f"{stamp} is in the future"
        assert reply["clock"]["time_scale"] == 100 and 0 <= reply["last_tick_age_s"] < 60
        assert reply["inputs"]["T_spindle_degC"]["unit"] == "degC"

        assert main(["status", "--config", str(config.path)]) == 0
        out = capsys.readouterr().out
        assert re.search(r"last tick \d+\.\d s ago \(", out), out
        assert re.search(r"T_spindle_degC: -?\d+\.\d+ degC", out), out
        assert "clock x100: machine time" in out and re.search(r"sign [+-]1 x model drift", out)

        assert main(["model", "load", str(config.model_path), "--config", str(config.path)]) == 0
        out = capsys.readouterr().out
        assert "already running example-gated-arx-y" in out and "no blend" in out
        assert main(["status", "--config", str(config.path), "--json"]) == 0
        model = json.loads(capsys.readouterr().out)
        assert model["counters"]["model_loads"] == 0
        assert model["model"]["pending"] is None and model["model"]["blending_from"] is None
    finally:
        daemon.send_signal(signal.SIGTERM)
        _, stderr = daemon.communicate(timeout=30)
    assert daemon.returncode == 0, stderr


def test_status_model_load_and_sigterm_on_a_running_daemon(tmp_path, capsys):
    """Against a running daemon: status shows it, model load switches it, SIGTERM stops it cleanly with state saved."""
    config = write_config(tmp_path, {"control_socket": str(short_socket()), "blend_s": 5})
    daemon = start_daemon(config, time_scale=10)
    try:
        ticked(config, 3)
        assert main(["status", "--config", str(config.path)]) == 0
        out = capsys.readouterr().out
        assert "example-gated-arx-y" in out and "T_spindle_degC" in out and "ticks" in out

        retuned = tmp_path / "retuned.yaml"
        retuned.write_text(config.model_path.read_text().replace("example-gated-arx-y", "retuned"))
        assert main(["model", "load", str(retuned), "--config", str(config.path)]) == 0
        assert "the daemon is switching to it" in capsys.readouterr().out
        deadline = time.monotonic() + 30
        while True:  # the switch happens at the next tick with complete inputs
            assert main(["status", "--config", str(config.path), "--json"]) == 0
            status = json.loads(capsys.readouterr().out)
            if status["model"]["name"] == "retuned" or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert status["model"]["name"] == "retuned" and status["counters"]["model_loads"] == 1
    finally:
        daemon.send_signal(signal.SIGTERM)
        _, stderr = daemon.communicate(timeout=30)
    assert daemon.returncode == 0, stderr
    assert json.loads(stderr.splitlines()[-1])["event"] == "stopped"
    assert (config.state_dir / "state.json").is_file()


def test_status_says_how_long_an_axis_has_asked_for_the_clamp(tmp_path, capsys):
    """An offset at its clamp shows under its axis at once, with how long and when it becomes a fault."""
    changes = {
        "control_socket": str(short_socket()),
        "drivers": {"machine": {"settings": {"start_s": 7200}}},
        "outputs": {"Y": {"max_offset_um": 0.05}},
    }
    config = write_config(tmp_path, changes)
    daemon = start_daemon(config, time_scale=100)
    try:
        deadline = time.monotonic() + 60
        while not request_sync(config.control_socket, {"cmd": "status"})["envelope"]["Y"][
            "outside"
        ]:
            assert time.monotonic() < deadline, "the target never reached the 0.05 um clamp"
            time.sleep(0.05)
        assert main(["status", "--config", str(config.path)]) == 0
        out = capsys.readouterr().out
        assert re.search(
            r"Y asks for the clamp: target \+0\.\d um, clamp ±0\.05 um, for \d+ s; a fault after 5 min",
            out,
        ), out
    finally:
        daemon.send_signal(signal.SIGTERM)
        _, stderr = daemon.communicate(timeout=30)
    assert daemon.returncode == 0, stderr
