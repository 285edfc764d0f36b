"""The status page in headless Debian chromium: it shows the running compd, draws its hour, changes nothing."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.service.loop.probemessages import ProbeRequest
from tests.report_screenshot import chromium, chromium_missing
from tests.service.httprun import BUNDLED_MODEL, RunningCompd, http_config, running_compd

pytestmark = pytest.mark.skipif(chromium_missing() is not None, reason=str(chromium_missing()))

#: A model name a config or model file could carry: the page must show it as text, never run it.
HOSTILE_NAME = 'twin-z <img src=x onerror="window.pwned=1"><script>window.pwned=2</script>'
HOLD_AT = 300
#: A probe of the residue offered at this tick (um): the page marks it and lists it.
PROBE_AT, PROBE_UM = 200, 0.8
#: How long the page may take to fetch and draw its first answers (ms); a hang guard, not a timing.
LOAD_TIMEOUT_MS = 60_000


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningCompd]:
    """compd on the simulated machine, its model named with markup in it, held at tick 300."""
    folder = tmp_path_factory.mktemp("page")
    model = folder / "model.yaml"
    text = BUNDLED_MODEL.read_text()
    model.write_text(text.replace('name: "twin-z"', f"name: {HOSTILE_NAME!r}"))
    config = http_config(folder, model=model)
    doc = yaml.safe_load(config.read_text())
    doc["probes"] = {"axes": {"Z": None}}  # probed through the socket (a gauge's result)
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    with running_compd(config, hold_at=PROBE_AT) as running:
        service, loop = running.service, running.loop
        assert service is not None and service.probing is not None and loop is not None
        probe = ProbeRequest("Z", PROBE_UM, service.clock.wall(), "test gauge", "residue")
        loop.call_soon_threadsafe(service.probing.offer, probe)
        running.hold_at(HOLD_AT)
        yield running


class Shown:
    """The page as chromium shows it once it has drawn, with its console errors and requests."""

    def __init__(self, browser: Any, run: RunningCompd) -> None:
        self.page = browser.new_page(viewport={"width": 1280, "height": 1000})
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(run.url)
        # Locators, not wait_for_function: its predicate is eval'd, which the page's policy forbids.
        self.page.locator("body[data-loaded]").wait_for(state="attached", timeout=LOAD_TIMEOUT_MS)
        self.page.locator("#chart-offsets polyline").first.wait_for(
            state="attached", timeout=LOAD_TIMEOUT_MS
        )

    def text(self, selector: str) -> str:
        return str(self.page.locator(selector).inner_text())


@pytest.fixture(scope="module")
def shown(run: RunningCompd) -> Iterator[Shown]:
    with chromium() as browser:
        yield Shown(browser, run)


def test_page_loads_cleanly_from_the_server_alone(shown: Shown, run: RunningCompd) -> None:
    """No console or script error, and every request goes to compd's own server (no CDN: shop floors are offline)."""
    assert shown.errors == []
    assert shown.requests and all(url.startswith(run.url) for url in shown.requests), shown.requests


def test_page_shows_inputs_offsets_status_and_provenance(shown: Shown, run: RunningCompd) -> None:
    """Each input with its value and health, the Z offset, the status word, the model's provenance and the faults."""
    status = run.json("/status.json")
    inputs = shown.text("#inputs")
    for name, entry in status["inputs"].items():
        assert name in inputs and f"{entry['value']:.2f}" in inputs
    assert shown.page.locator("#inputs tbody tr").count() == len(status["inputs"])
    offsets = shown.text("#offsets tbody")
    assert offsets.startswith("Z") and f"{status['offsets_um']['Z']:.2f}" in offsets
    assert f"{status['status_word']} (0x" in shown.text("#status")
    assert shown.text("#level") in {"ok", "degraded", "faulted"}
    # Beside it, what the level does not say: the spindle's one sensor (its second taken away).
    assert shown.text("#not-assured") == (
        "not assured on Z: T_spindle_degC not verifiable to its 1.56 um tolerance"
    )
    model = shown.text("#model")
    assert status["model"]["sha256"] in model and "97.9 %" in model and "oe" in model
    faults = shown.text("#faults")
    assert "plc" in faults and "link down" in faults and "T_spindle_degC" in faults
    assert str(status["counters"]["ticks"]) in shown.text("#counters")


def test_names_from_files_are_shown_as_text_not_run(shown: Shown) -> None:
    """A model named with HTML in it is shown literally; no element or script of it exists."""
    assert shown.text("#model-name") == HOSTILE_NAME
    assert shown.page.evaluate("window.pwned === undefined")
    assert shown.page.locator("main img, header img, main script").count() == 0


def test_chart_draws_the_hour(shown: Shown, run: RunningCompd) -> None:
    """The offsets chart has a line for Z through the ticks so far; the temperatures chart one per degC input."""
    points = shown.page.eval_on_selector_all(
        "#chart-offsets polyline[data-series='Z']",
        "lines => lines.reduce((n, l) => n + l.getAttribute('points').trim().split(' ').length, 0)",
    )
    assert points >= 100
    temperatures = shown.page.eval_on_selector_all(
        "#chart-inputs polyline", "lines => [...new Set(lines.map(l => l.dataset.series))].sort()"
    )
    units = run.json("/history.json")["units"]
    assert temperatures == sorted(name for name, unit in units.items() if unit == "degC")
    assert len(temperatures) >= 4
    assert "Z" in shown.text("#legend-offsets")


def test_page_has_no_write_controls_and_posts_are_refused(shown: Shown, run: RunningCompd) -> None:
    """No form, button or input on the page; a POST from it is 405 and the service is as it was."""
    controls = shown.page.locator("form, button, input, select, textarea, [contenteditable]")
    assert controls.count() == 0
    ticks = run.json("/status.json")["counters"]["ticks"]
    for path in ("/", "/status.json", "/metrics"):
        status = shown.page.evaluate(
            "p => fetch(p, {method: 'POST', body: 'x'}).then(r => r.status)", path
        )
        assert status == 405
    assert run.json("/status.json")["counters"]["ticks"] == ticks


def test_screenshot(shown: Shown, tmp_path_factory: pytest.TempPathFactory) -> None:
    """A full-page screenshot renders (kept with the test's files, for a person to look at)."""
    png = Path(tmp_path_factory.mktemp("shot")) / "status-page.png"
    shown.page.screenshot(path=str(png), full_page=True)
    assert png.stat().st_size > 10_000


def test_charts_mark_each_fault_start_with_its_reason(shown: Shown, run: RunningCompd) -> None:
    """Each fault the page lists is a red vertical mark on the offsets chart, its reason as the tooltip."""
    listed = run.json("/page.json")["faults"]
    marks = shown.page.locator("#chart-offsets line.mark.fault")
    assert listed and marks.count() == len(listed)
    tooltips = " ".join(marks.locator("title").all_text_contents())
    assert "link down" in tooltips and "T_spindle_degC" in tooltips


def test_probes_are_listed_and_marked_on_the_chart(shown: Shown, run: RunningCompd) -> None:
    """A probe taken is a green mark at its touch (result and innovation as the tooltip) and a row
    per probed axis: its last result, innovation and the shift's RMS, as /page.json says."""
    page = run.json("/page.json")
    z = page["probes"]["Z"]
    assert z["last"]["result"] == "accepted" and z["shift_probes"] == 1
    assert [m["kind"] for m in page["probe_marks"]] == ["probe"]
    marks = shown.page.locator("#chart-offsets line.mark.probe")
    assert marks.count() == 1
    tooltip = marks.locator("title").all_text_contents()[0]
    assert "accepted" in tooltip and f"measured {PROBE_UM:+.2f} um" in tooltip
    listed = shown.text("#probes tbody")
    assert listed.startswith("Z") and "accepted" in listed
    assert f"{z['last']['innovation_um']:.2f}" in listed and f"{z['shift_rms_um']:.2f}" in listed
    assert shown.page.locator("#probes-section").is_visible()
