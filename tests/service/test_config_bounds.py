"""A config number that would overflow where it is used is a config error naming the file, the key and the fix."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from compd.errors import ConfigFileError
from compd.service.config.docbase import MAX_NUMBER, MAX_SECONDS
from tests.service.daemon_setup import write_config

TELEMETRY = {"machine_id": "m", "host": "127.0.0.1"}


@pytest.mark.parametrize(
    ("changes", "place"),
    [
        ({"outputs": {"Y": {"max_offset_um": 1e308}}}, "outputs.Y.max_offset_um"),
        ({"outputs": {"Y": {"max_rate_um_per_s": float("inf")}}}, "outputs.Y.max_rate_um_per_s"),
        ({"period_s": 1e300}, "period_s"),
        ({"signals": {"T_spindle_degC": {"checks": {"stale_s": 1e12}}}}, "stale_s"),
        ({"state": {"save_every_ticks": 10**40}}, "state.save_every_ticks"),
        ({"recorder": {"enabled": True, "max_total_bytes": 1e300}}, "recorder.max_total_bytes"),
        ({"drivers": {"machine": {"timeout_s": 1e20}}}, "drivers.machine.timeout_s"),
        ({"drivers": {"machine": {"settings": {"start_s": 1e300}}}}, "drivers.machine.settings"),
        ({"telemetry": TELEMETRY | {"keepalive_s": 10**40}}, "telemetry.keepalive_s"),
        ({"telemetry": TELEMETRY | {"queue_size": 10**40}}, "telemetry.queue_size"),
        ({"telemetry": TELEMETRY | {"reconnect_max_s": 10**12}}, "telemetry.reconnect_max_s"),
    ],
    ids=lambda v: v if isinstance(v, str) else None,
)
def test_a_number_beyond_any_machine_is_refused_naming_the_key(
    tmp_path: Path, changes: dict[str, Any], place: str
):
    """1e308, inf, 10**40 and the like are refused at load, with the key's place, not an OverflowError later."""
    with pytest.raises(ConfigFileError) as raised:
        write_config(tmp_path, changes)
    message = str(raised.value)
    assert str(tmp_path / "compd.yaml") in message and place in message, message


def test_the_keep_alive_is_bounded_by_what_mqtt_carries(tmp_path: Path):
    """telemetry.keepalive_s above 65535 s (16 bits in MQTT's CONNECT) is refused; 65535 is taken."""
    write_config(tmp_path, {"telemetry": TELEMETRY | {"keepalive_s": 65535}})
    with pytest.raises(ConfigFileError, match=r"telemetry\.keepalive_s"):
        write_config(tmp_path, {"telemetry": TELEMETRY | {"keepalive_s": 65536}})


def test_numbers_up_to_the_bound_are_taken(tmp_path: Path):
    """Large values within the bounds (a clamp of 1e6 um, 1 PB of recordings, a 1e9 s resume age) are taken."""
    config = write_config(
        tmp_path,
        {
            "outputs": {"Y": {"max_offset_um": 1e6}},
            "recorder": {"enabled": True, "max_total_bytes": int(MAX_NUMBER)},
            "state": {"resume_max_age_s": MAX_SECONDS},
        },
    )
    assert config.doc.outputs["Y"].max_offset_um == 1e6


def test_check_config_exits_with_the_error(tmp_path: Path):
    """compd check-config on max_offset_um: 1e308 exits 2 with one error naming the key, no traceback."""
    config = write_config(tmp_path)
    path = config.path
    path.write_text(path.read_text().replace("max_offset_um: 50", "max_offset_um: 1e308"))
    done = subprocess.run(
        [sys.executable, "-m", "compd.cli", "check-config", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert "outputs.Y.max_offset_um" in done.stderr and "Traceback" not in done.stderr
