"""/metrics in Prometheus's terms: base units, one metric per quantity, flags, info, links, process; promtool clean."""

from __future__ import annotations

import math
import shutil
import subprocess
from collections.abc import Iterator

import pytest

from compd import __version__
from compd.service.loop.safety import Flag
from tests.metricsrender import MACHINE_ID, Render, rendered_with_broker
from tests.mosquitto import mosquitto_binary

pytestmark = pytest.mark.skipif(
    mosquitto_binary() is None, reason="mosquitto is not installed: run .ci/install-system-packages"
)
PROMTOOL = shutil.which("promtool")


@pytest.fixture(scope="module")
def render(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Render]:
    with rendered_with_broker(tmp_path_factory.mktemp("metrics")) as render:
        yield render


def test_promtool_finds_nothing_to_complain_about(render: Render) -> None:
    """``promtool check metrics`` (Prometheus's own linter) passes the exposition with no remark."""
    if PROMTOOL is None:
        pytest.skip("promtool is missing: .ci/install-system-packages installs Debian's prometheus")
    checked = subprocess.run(
        [PROMTOOL, "check", "metrics"], input=render.text, capture_output=True, text=True
    )
    assert checked.returncode == 0 and checked.stdout == checked.stderr == "", checked


def test_names_are_in_base_units_and_no_created_series(render: Render) -> None:
    """No ``_um``, ``_percent`` or ``_created`` series; offsets in meters equal the status's um x 1e-6."""
    names = render.families
    assert not [n for n in names if n.endswith(("_um", "_percent", "_created"))]
    assert "compd_signal_value" not in names
    axis = (("axis", "Z"),)
    status = render.status
    for metric, key in [
        ("compd_offset_meters", "offsets_um"),
        ("compd_offset_held_meters", "offsets_held_um"),
        ("compd_offset_target_meters", "targets_um"),
    ]:
        assert math.isclose(render.samples[metric][axis], status[key]["Z"] * 1e-6)
    (fit,) = render.samples["compd_model_fit_ratio"].values()
    assert math.isclose(fit, 0.9788898877080075)


def test_one_metric_per_physical_quantity(render: Render) -> None:
    """Temperatures in ``compd_signal_celsius``, speeds in revolutions per second, power in watts; no unit label."""
    factors = {
        "degC": ("compd_signal_celsius", 1.0),
        "rpm": ("compd_signal_revolutions_per_second", 1 / 60),
        "kW": ("compd_signal_watts", 1e3),
    }
    for name, entry in render.status["inputs"].items():
        metric, factor = factors[entry["unit"]]
        assert math.isclose(render.samples[metric][(("signal", name),)], entry["value"] * factor)
    for metric, _ in factors.values():
        assert all(labels == (("signal", labels[0][1]),) for labels in render.samples[metric])


def test_status_flags_are_their_own_series(render: Render) -> None:
    """``compd_status_flag{flag}`` has a 0/1 series for each bit of the status word, as the word says."""
    word = render.status["status_word"]
    flags = render.samples["compd_status_flag"]
    assert {labels[0][1] for labels in flags} == {f.name.lower() for f in Flag}
    assert (("flag", "clamped"),) in flags
    for flag in Flag:
        assert flags[(("flag", flag.name.lower()),)] == float(bool(word & flag))


def test_info_mqtt_recorder_and_process_families(render: Render) -> None:
    """An info metric (version, machine_id), the MQTT link's counters, the recorder's health and ``process_*``."""
    assert render.samples["compd_info"] == {
        (("machine_id", MACHINE_ID), ("version", __version__)): 1.0
    }
    telemetry = render.status["telemetry"]
    assert render.samples["compd_mqtt_connected"][()] == 1.0
    assert render.samples["compd_mqtt_published_total"][()] == telemetry["published"] > 0
    assert render.samples["compd_mqtt_dropped_total"][()] == telemetry["dropped"]
    assert render.samples["compd_mqtt_acknowledged_total"][()] == telemetry["acknowledged"]
    assert render.samples["compd_mqtt_connections_total"][()] == telemetry["connections"] == 1
    assert render.samples["compd_recorder_up"][()] == 1.0
    assert render.samples["compd_recorder_faults_total"][()] == 0
    assert render.samples["process_cpu_seconds_total"][()] > 0
    assert render.samples["process_resident_memory_bytes"][()] > 0
