"""compd's HTTP server on the simulated machine: /metrics as Prometheus reads it, the page's JSON, read-only."""

from __future__ import annotations

import json
import math
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from compd.errors import CompdError, ConfigFileError
from compd.service.config.docs import HttpDoc
from compd.service.config.loading import load_config
from tests.clirun import compd
from tests.service.httprun import RunningCompd, http_config, running_compd

HOLD_AT = 150

FAMILIES = {
    "compd_tick_lateness_seconds": "histogram",
    "compd_tick_cpu_seconds": "histogram",
    "compd_driver_io_seconds": "histogram",
    "compd_ticks": "counter",
    "compd_overruns": "counter",
    "compd_faults": "counter",
    "compd_driver_faults": "counter",
    "compd_driver_reconnects": "counter",
    "compd_driver_up": "gauge",
    "compd_driver_writes_refused": "gauge",
    "compd_offset_meters": "gauge",
    "compd_offset_held_meters": "gauge",
    "compd_offset_target_meters": "gauge",
    "compd_signal_celsius": "gauge",
    "compd_signal_revolutions_per_second": "gauge",
    "compd_signal_watts": "gauge",
    "compd_signal_health": "gauge",
    "compd_status_word": "gauge",
    "compd_status_level": "gauge",
    "compd_heartbeat": "gauge",
    "compd_model_info": "gauge",
    "compd_model_fit_ratio": "gauge",
    "compd_model_loads": "counter",
    "compd_model_fault": "gauge",
}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningCompd]:
    """compd on the simulated machine (an input NaN at 30 s, the PLC off the network at 100 s), held at tick 150."""
    with running_compd(http_config(tmp_path_factory.mktemp("http")), hold_at=HOLD_AT) as running:
        yield running


def scrape(run: RunningCompd) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    """``/metrics`` parsed by Prometheus's own parser: sample name -> sorted labels -> value."""
    status, headers, body = run.get("/metrics")
    assert status == 200 and headers["Content-Type"].startswith("text/plain; version=0.0.4")
    samples: dict[str, dict[tuple[tuple[str, str], ...], float]] = {}
    types = {}
    for family in text_string_to_metric_families(body.decode()):
        types[family.name] = family.type
        for sample in family.samples:
            samples.setdefault(sample.name, {})[tuple(sorted(sample.labels.items()))] = sample.value
    for name, kind in FAMILIES.items():
        assert types.get(name) == kind, (name, types.get(name))
    return samples


def test_metrics_equal_the_status_and_move_with_the_ticks(run: RunningCompd) -> None:
    """Every family is there; counters, offsets, inputs equal ``/status.json`` at one instant; they move with time."""
    metrics, status = scrape(run), run.json("/status.json")
    counters = status["counters"]
    assert metrics["compd_ticks_total"][()] == counters["ticks"] == HOLD_AT
    assert metrics["compd_tick_lateness_seconds_count"][()] == HOLD_AT
    assert metrics["compd_tick_cpu_seconds_count"][()] == HOLD_AT
    assert metrics["compd_tick_cpu_seconds_sum"][()] > 0
    reads = metrics["compd_driver_io_seconds_count"][(("driver", "plc"), ("operation", "read"))]
    assert 0 < reads <= HOLD_AT  # no read while the link was down
    faults = {labels[0][1]: v for labels, v in metrics["compd_faults_total"].items()}
    assert faults["signal"] == counters["signal_faults"] >= 1  # the NaN input
    assert faults["driver"] == counters["driver_faults"] >= 1  # the PLC off the network
    assert faults["write"] == counters["write_failures"]
    assert (
        metrics["compd_driver_reconnects_total"][(("driver", "plc"),)]
        == counters["reconnects"]
        >= 1
    )
    assert metrics["compd_driver_up"][(("driver", "plc"),)] == 1.0
    z = (("axis", "Z"),)
    assert math.isclose(metrics["compd_offset_meters"][z], status["offsets_um"]["Z"] * 1e-6)
    assert math.isclose(
        metrics["compd_offset_held_meters"][z], status["offsets_held_um"]["Z"] * 1e-6
    )
    assert math.isclose(metrics["compd_offset_target_meters"][z], status["targets_um"]["Z"] * 1e-6)
    assert metrics["compd_status_word"][()] == status["status_word"]
    assert metrics["compd_heartbeat"][()] == status["heartbeat"]
    for name, entry in status["inputs"].items():
        quantity, factor = {
            "degC": ("celsius", 1.0),
            "rpm": ("revolutions_per_second", 1 / 60),
            "kW": ("watts", 1e3),
        }[entry["unit"]]
        value = metrics[f"compd_signal_{quantity}"][(("signal", name),)]
        assert math.isclose(value, entry["value"] * factor)
        assert metrics["compd_signal_health"][(("signal", name),)] == 0  # ok again by tick 150
    model = status["model"]
    key = (("model", model["name"]), ("output", "disp_z_um"), ("sha256", model["sha256"]))
    assert math.isclose(metrics["compd_model_fit_ratio"][key], 0.9788898877080075)
    assert metrics["compd_model_loads_total"][()] == 0

    run.hold_at(2 * HOLD_AT)
    later, status = scrape(run), run.json("/status.json")
    assert later["compd_ticks_total"][()] == status["counters"]["ticks"] == 2 * HOLD_AT
    assert later["compd_tick_lateness_seconds_count"][()] == 2 * HOLD_AT
    key = (("driver", "plc"), ("operation", "write"))
    assert (
        later["compd_driver_io_seconds_count"][key] > metrics["compd_driver_io_seconds_count"][key]
    )
    assert math.isclose(later["compd_offset_meters"][z], status["offsets_um"]["Z"] * 1e-6)
    assert later["compd_offset_meters"][z] != metrics["compd_offset_meters"][z]


def test_status_json_is_what_compd_status_prints(run: RunningCompd) -> None:
    """``GET /status.json`` is the same snapshot ``compd status --json`` gets over the control socket."""
    printed = json.loads(compd("status", "--config", run.config.path, "--json"))
    assert printed.pop("ok") is True  # the control protocol's envelope, not the snapshot
    assert run.json("/status.json") == printed


def test_history_is_the_last_ticks_thinned_to_the_points_asked(run: RunningCompd) -> None:
    """``/history.json`` holds one row a tick (period 1 s) up to now, thinned to ``points``; bad ``points`` is a 400."""
    full = run.json("/history.json?points=3600")
    ticks = run.json("/status.json")["counters"]["ticks"]
    assert len(full["t_unix_s"]) == ticks and full["every_ticks"] == 1
    assert full["offsets_um"]["Z"][-1] == run.json("/status.json")["offsets_um"]["Z"]
    levels = [w & 0b11 for w in full["status_word"]]
    assert (
        levels[0] == 0 and 2 in levels
    )  # faulted while the NaN input was (held values are charted)
    thin = run.json("/history.json?points=50")
    assert 25 <= len(thin["t_unix_s"]) <= 50 and thin["t_unix_s"][-1] == full["t_unix_s"][-1]
    assert thin["units"]["T_spindle_degC"] == "degC"
    for bad in ("0", "x", "100000"):
        status, _, body = run.get(f"/history.json?points={bad}")
        assert status == 400 and b"points" in body


def test_page_json_lists_the_faults_and_the_models_provenance(run: RunningCompd) -> None:
    """The page's document: the model's provenance, the status word by name, the faults newest first."""
    page = run.json("/page.json")
    assert page["model"]["method"] == "oe" and page["model"]["fit_percent"]["disp_z_um"] > 97
    assert page["status"]["level"] in {"ok", "degraded"}
    kinds = [f["kind"] for f in page["faults"]]
    assert "driver" in kinds and "signal" in kinds
    times = [f["at_unix_s"] for f in page["faults"]]
    assert times == sorted(times, reverse=True)
    nan = [f for f in page["faults"] if f["source"] == "T_spindle_degC"]
    assert any("below min" in f["message"] for f in nan)
    assert page["probes"] is None and page["probe_marks"] == []  # the config probes nothing


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "PATCH"])
@pytest.mark.parametrize("path", ["/", "/metrics", "/status.json", "/nowhere"])
def test_nothing_but_get_and_head_is_answered(run: RunningCompd, method: str, path: str) -> None:
    """Any other method on any path is 405 naming GET and HEAD: nothing can be changed over HTTP."""
    status, headers, _ = run.get(path, method)
    assert status == 405 and headers["Allow"] == "GET,HEAD"


def test_pages_carry_a_policy_that_allows_no_form_and_no_other_host(run: RunningCompd) -> None:
    """HEAD works; every answer forbids forms, framing and any source but the server itself."""
    for path in ("/", "/page.js", "/page.css", "/metrics", "/status.json"):
        status, headers, body = run.get(path, "HEAD")
        assert status == 200 and body == b""
        policy = headers["Content-Security-Policy"]
        assert "form-action 'none'" in policy and "default-src 'none'" in policy
        assert headers["X-Content-Type-Options"] == "nosniff"
    assert run.get("/nowhere")[0] == 404


def test_http_section_defaults_to_the_loopback_address() -> None:
    """Unset, the server listens on 127.0.0.1 only, port 9780: opening it wider is the config's decision."""
    doc = HttpDoc()
    assert (doc.listen, doc.port, doc.enabled) == ("127.0.0.1", 9780, True)


def test_bad_http_section_names_the_place(tmp_path: Path) -> None:
    """An unknown key or a port out of range is a config error naming ``http``."""
    path = http_config(tmp_path)
    doc = yaml.safe_load(path.read_text())
    for http, place in (({"prot": 9000}, "http.prot"), ({"port": 70000}, "http.port")):
        doc["http"] = http
        path.write_text(yaml.safe_dump(doc))
        with pytest.raises(ConfigFileError, match=place.replace(".", r"\.")):
            load_config(path)


def test_disabled_http_builds_no_server(tmp_path: Path) -> None:
    """``http: {enabled: false}``: no server, no metrics, nothing measured in the tick."""
    from compd.service.daemon import Service
    from compd.service.loop.clock import VirtualClock

    config = load_config(http_config(tmp_path, enabled=False))
    assert Service(config, clock=VirtualClock(), control=False).http is None


def test_a_port_in_use_stops_the_start_naming_the_option(tmp_path: Path) -> None:
    """A second compd on the same port does not start: the error names the config and ``http.port``."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        path = http_config(tmp_path, port=port)
        run = RunningCompd(path, first_hold=1)
        run.thread.start()
        run.thread.join(300)
    assert isinstance(run.error, CompdError)
    assert str(path) in str(run.error) and "'http.port'" in str(run.error)


def test_page_files_ship_in_the_wheel() -> None:
    """Each file the server serves exists and matches pyproject's package-data for compd.service."""
    import fnmatch
    import tomllib

    from compd.service.http.server import PAGE_DIR, PAGE_FILES

    root = Path(__file__).parents[2]
    setuptools = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = setuptools["package-data"]["compd.service.http"]
    for file, _ in PAGE_FILES.values():
        assert (PAGE_DIR / file).is_file()
        assert any(fnmatch.fnmatch(f"statuspage/{file}", p) for p in patterns), file


def test_a_service_ended_as_killed_stops_listening_on_its_http_port(tmp_path: Path) -> None:
    """A service left as SIGKILL leaves it (the soak's in-process kills) closes its HTTP port, as the OS would."""
    import asyncio

    from compd.service.daemon import Service
    from compd.service.loop.clock import VirtualClock

    config = load_config(http_config(tmp_path))
    service = Service(config, clock=VirtualClock(), control=False)
    ports: list[int] = []
    service.subscribe(lambda _: ports.append(service.http.port) if service.http else None)
    service.leave_as_killed()
    asyncio.run(service.run(duration_s=3.0))
    with socket.socket() as client, pytest.raises(ConnectionRefusedError):
        client.connect(("127.0.0.1", ports[0]))
