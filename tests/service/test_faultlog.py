"""Faults are logged by episode: ERROR once, DEBUG while they last, INFO when they clear."""

from __future__ import annotations

import asyncio

import structlog
from structlog.testing import capture_logs

from compd.faultlog import Event, FaultLog
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.store.state import STATE_FILE

from .daemon_setup import write_config


def test_one_error_per_episode_debug_while_it_lasts_info_when_it_clears():
    """Two episodes of three failures each: two ERRORs, four DEBUGs, two INFOs, in that order."""
    fault = FaultLog(structlog.get_logger("test"), driver="plc")
    with capture_logs() as events:
        fault.cleared("works")  # no episode: nothing to say
        for _ in range(2):
            for _ in range(3):
                fault.failed("read failed", error="gone")
            fault.cleared("works again")
    assert [(e["log_level"], e["event"]) for e in events] == 2 * [
        ("error", "read failed"),
        ("debug", "read failed again"),
        ("debug", "read failed again"),
        ("info", "works again"),
    ]
    assert all(e["driver"] == "plc" for e in events) and fault.episodes == 2 and not fault.active


def test_an_attached_sink_hears_each_episode_once_start_and_end():
    """The event sink (the telemetry) hears an episode's fault and its cleared (then what it was), not its repeats."""
    fault = FaultLog(structlog.get_logger("test"), driver="plc")
    heard: list[Event] = []
    fault.sink = heard.append
    for _ in range(3):
        fault.failed("read failed", error="gone")
    fault.cleared("driver reconnected", also="reconnected", after_failures=3)
    assert heard == [
        Event("fault", "read failed", {"driver": "plc", "error": "gone"}),
        Event("cleared", "driver reconnected", {"driver": "plc", "after_failures": 3}),
        Event("reconnected", "driver reconnected", {"driver": "plc", "after_failures": 3}),
    ]


def test_failing_state_saves_log_one_error_then_info_when_they_work_again(tmp_path):
    """Saves failing every 60 ticks for 5 minutes log one ERROR (DEBUG after); the first save that works logs INFO."""
    config = write_config(tmp_path, {"state": {"save_every_ticks": 60}})
    blocker = config.state_dir / STATE_FILE / "in the way"  # a directory where state.json goes
    service = Service(config, clock=VirtualClock(), control=False, background_saves=False)
    ticks = []

    def on_tick(record: object) -> None:
        ticks.append(record)
        if len(ticks) == 1:
            blocker.mkdir(parents=True)
        if len(ticks) == 330:  # the way is clear again
            blocker.rmdir()
            blocker.parent.rmdir()

    service.subscribe(on_tick)
    with capture_logs() as events:
        asyncio.run(service.run(duration_s=420))
    saves = [(e["log_level"], e["event"]) for e in events if "save" in e["event"]]
    assert saves[0] == ("error", "cannot save state")
    assert saves.count(("error", "cannot save state")) == 1
    assert saves.count(("debug", "cannot save state again")) >= 3
    assert ("info", "state saved again") in saves
    assert (config.state_dir / STATE_FILE).is_file()
