"""``/healthz`` of the real HTTP server on the simulated machine: 200 while ticks are on time and the
outputs healthy, 503 with the reason while the PLC is off the network or the loop stands still;
``/status.json`` answers as before either way."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.service.loop.probemessages import ProbeRequest
from tests.service.httprun import RunningCompd, http_config, running_compd

#: Ticks (simulated s) before the faults of :data:`tests.service.httprun.FAULTS`, during the PLC's
#: drop (100-110 s) and after it.
BEFORE, DROPPED, AFTER = 20, 105, 150


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningCompd]:
    with running_compd(http_config(tmp_path_factory.mktemp("healthz")), hold_at=BEFORE) as running:
        yield running


def healthz(run: RunningCompd) -> tuple[int, dict[str, Any]]:
    status, headers, body = run.get("/healthz")
    assert headers["Content-Type"].startswith("application/json")
    return status, json.loads(body)


def test_healthy_then_503_naming_the_dropped_plc_then_healthy_again(run: RunningCompd) -> None:
    """Before the faults 200 and no problems; the PLC off the network 503 "driver plc down"; back, 200.
    Throughout, a warning: the spindle's one sensor (its second taken away) cannot be verified to Z's
    tolerance."""
    warnings = ["not assured on Z: T_spindle_degC not verifiable to its 1.56 um tolerance"]
    assert healthz(run) == (
        200,
        {"healthy": True, "level": "ok", "problems": [], "warnings": warnings},
    )

    run.hold_at(DROPPED)
    status, answer = healthz(run)
    assert status == 503 and not answer["healthy"]
    assert any(p.startswith("driver plc down") for p in answer["problems"]), answer
    assert "the last tick's offsets were not written" in answer["problems"]
    # /status.json is not a health check: it answers 200 with its usual document.
    assert set(run.json("/status.json")["drivers"].items()) == {("plc", "down")}
    assert run.get("/healthz", method="HEAD")[0] == 503

    run.hold_at(AFTER)
    status, answer = healthz(run)
    assert (status, answer["problems"], answer["warnings"]) == (200, [], warnings), answer


def test_a_loop_that_stands_still_is_503(run: RunningCompd) -> None:
    """Held before a tick while its clock runs on 10 s (a stuck tick): 503 "no tick for 10.0 s"."""
    assert run.clock is not None
    run.hold_at(AFTER + 1)
    inner_wall = run.clock.inner.wall
    run.clock.inner.wall = lambda: inner_wall() + 10.0  # the loop's time goes on, no tick runs
    try:
        status, answer = healthz(run)
    finally:
        run.clock.inner.wall = inner_wall
    assert status == 503, answer
    assert answer["problems"][0].startswith("no tick for 1"), answer
    assert healthz(run)[0] == 200


def test_a_failing_probe_update_is_503_naming_it(tmp_path: Path) -> None:
    """An update that overflows (a bug): the probe refused, learning on, and /healthz 503 saying so."""
    path = http_config(tmp_path)
    doc = yaml.safe_load(path.read_text())
    doc["probes"] = {"axes": {"Z": None}}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))

    def overflow(*args: object) -> None:
        raise OverflowError("(34, 'Numerical result out of range')")

    with running_compd(path, hold_at=BEFORE) as run:
        assert run.service is not None and run.loop is not None
        probing = run.service.probing
        assert probing is not None and healthz(run)[0] == 200
        probing.learners["disp_z_um"].updater._probe = overflow  # type: ignore[method-assign]
        request = ProbeRequest("Z", 1.0, run.service.clock_wall(), "test")
        run.loop.call_soon_threadsafe(probing.offer, request)
        run.hold_at(BEFORE + 3)
        status, answer = healthz(run)
    assert status == 503, answer
    assert any(
        p.startswith("probe learning fails: probe update failed") for p in answer["problems"]
    )
    assert probing.off is None
