"""The service on the simulated machine and virtual time: hours replayed in seconds."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.model.run import simulate
from compd.service.control.modelload import load_request
from compd.service.control.socket import request
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.safety import SIGNAL_BIT0, Flag, Level
from compd.service.loop.signals import Health
from compd.service.store.state import load_state

from .daemon_setup import run, short_socket, ticked, write_config

SLEW_UM = 1.0  # max_rate_um_per_s of the bundled simulated config, at 1 s


def offsets(records, axis="Y"):
    return np.array([r.offsets_um[axis] for r in records])


@pytest.fixture(scope="module")
def two_hours(tmp_path_factory):
    """Two hours of the bundled simulated config, started at 2 h into the example data (spindle running)."""
    directory = tmp_path_factory.mktemp("two_hours")
    config = write_config(directory, {"drivers": {"machine": {"settings": {"start_s": 7200}}}})
    return run(config, 7200.0)


def test_offsets_follow_the_model(two_hours):
    """Every written offset is minus the model's free-run output on the inputs read (checked against simulate)."""
    service, records = two_hours
    slot = service.compensator.active
    inputs = np.array([[r.values[s] for s in slot.compiled.signals] for r in records])
    reference = simulate(slot.compiled, inputs, slot.compiled.steady_state(inputs[0]))
    assert len(records) == 7201
    assert_allclose(offsets(records), -reference.outputs[:, 0], atol=1e-9)
    assert np.ptp(offsets(records)) > 5.0  # the offsets really move
    assert service.drivers["machine"].written["comp_y_um"] == records[-1].offsets_um["Y"]


def test_status_word_and_heartbeat_are_written(two_hours):
    """The last tick wrote status ok and a heartbeat equal to the tick count; shutdown wrote STOPPED."""
    service, records = two_hours
    assert {r.status for r in records} == {int(Level.OK)}
    assert [r.heartbeat for r in records[:3]] == [1, 2, 3]
    written = service.drivers["machine"].written
    assert written["compd_heartbeat"] == 7201
    assert int(written["compd_status"]) & Flag.STOPPED


def test_status_snapshot(two_hours):
    """The status snapshot names the model and holds inputs, offsets and counters."""
    status = two_hours[0].status()
    assert status["model"]["name"] == "example-gated-arx-y" and status["model"]["started"]
    assert status["inputs"]["T_spindle_degC"]["health"] == "ok"
    assert status["counters"]["ticks"] == 7201 and status["counters"]["overruns"] == 0


def test_sensor_fault_freezes_then_ramps(tmp_path):
    """A NaN sensor is held hold_s, then its axis freezes for fault_ramp_after_s, then ramps to 0 at the slew limit."""
    fault = {"kind": "nan", "address": "T_spindle_degC", "start_s": 3000, "duration_s": 900}
    config = write_config(
        tmp_path,
        {
            "drivers": {"machine": {"settings": {"start_s": 7200, "faults": [fault]}}},
            "safety": {"on_fault": "ramp", "fault_ramp_after_s": 60},
        },
    )
    _, records = run(config, 4500.0)
    health = [r.health["T_spindle_degC"] for r in records]
    assert health[2999] is Health.OK and health[3000] is Health.HELD
    assert health[3029] is Health.HELD and health[3030] is Health.FAULTED
    y = offsets(records)
    assert abs(y[3029]) > 1.0
    assert np.all(y[3030:3090] == y[3029])  # frozen
    assert abs(y[3090] - y[3089]) == pytest.approx(SLEW_UM)  # ramps at the slew limit
    assert np.all(y[3100:3900] == 0.0)
    word = records[3100].status
    assert word & 0b11 == Level.FAULTED and word & (1 << SIGNAL_BIT0)
    assert health[3900] is Health.OK and records[-1].status == Level.OK
    assert np.all(np.abs(np.diff(y)) <= SLEW_UM + 1e-12)  # recovery slews back too
    assert y[-1] == pytest.approx(-records[-1].model_outputs["disp_y_um"])


def test_killed_daemon_resumes_without_a_jump(tmp_path):
    """A daemon killed after an hour and restarted 5 s later resumes its last saved state: no jump in the offsets."""
    changes = {
        "drivers": {"machine": {"settings": {"start_s": 7200}}},
        "state": {"save_every_ticks": 10},
    }
    config = write_config(tmp_path, changes)
    first = Service(config, clock=VirtualClock(), control=False, background_saves=False)
    first.leave_as_killed()  # no save at shutdown, only the periodic ones
    _, before = run(config, 3604.0, service=first)
    saved = load_state(config.state_dir)
    assert saved is not None and saved.ticks == 3600  # the last periodic save
    last = before[saved.ticks - 1]  # the tick whose state was saved
    assert saved.offsets_um["Y"] == last.offsets_um["Y"] and abs(last.offsets_um["Y"]) > 2.0

    # The machine went on for 5 s (and the data with it) while compd was down.
    changes["drivers"]["machine"]["settings"]["start_s"] = 7200 + (saved.ticks - 1) + 5
    restarted = write_config(tmp_path, changes)
    clock = VirtualClock(wall0_unix_s=saved.saved_at_unix_s + 5.0)
    second, after = run(restarted, 600.0, clock=clock)
    assert second.resumed
    assert abs(after[0].offsets_um["Y"] - last.offsets_um["Y"]) < 0.05
    assert np.all(np.abs(np.diff(offsets(after))) <= SLEW_UM + 1e-12)

    (config.state_dir / "state.json").unlink()
    cold, fresh = run(restarted, 10.0, clock=VirtualClock(wall0_unix_s=clock.wall()))
    assert not cold.resumed and abs(fresh[0].offsets_um["Y"]) < 1e-9  # what resuming avoids


def bad_and_good_models(directory: Path) -> tuple[Path, Path]:
    text = Path(load_model(write_config(directory).model_path).path).read_text()
    bad = directory / "unstable.yaml"
    bad.write_text(text.replace("den: [1.0, -0.998889505944279]", "den: [1.0, -1.5]"))
    good = directory / "retuned.yaml"
    good.write_text(
        text.replace("gain: 1.0       # g2", "gain: 1.6       # g2").replace(
            "name: example-gated-arx-y", "name: retuned"
        )
    )
    return bad, good


def test_hot_load_refuses_a_bad_model_and_blends_a_good_one(tmp_path):
    """Over the control socket a bad model is refused while the old one runs; a good one switches without a jump."""
    bad, good = bad_and_good_models(tmp_path)
    socket = short_socket()
    config = write_config(
        tmp_path,
        {
            "drivers": {"machine": {"settings": {"start_s": 7200}}},
            "control_socket": str(socket),
            "blend_s": 120,
        },
    )
    service = Service(config, clock=VirtualClock(), control=True)
    records = []
    service.subscribe(records.append)
    replies = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        counters = service.compensator.counters
        await ticked(service, task, 300)
        # Hang guards, not bounds: on virtual time the loop ticks back to back and shares the
        # interpreter with the model check in its worker thread (a load's reply took 0.15-4.6 s
        # on an idle machine, once over the client's default 5 s under the suite's load).
        wait_s = 120.0
        replies["bad"] = await request(
            socket, load_request(bad.read_bytes(), bad), timeout_s=wait_s
        )
        replies["status"] = await request(socket, {"cmd": "status"}, timeout_s=wait_s)
        replies["good"] = await request(
            socket, load_request(good.read_bytes(), good), timeout_s=wait_s
        )
        # Counted from the reply: virtual ticks race ahead while the daemon checks the model.
        stop_at = counters.ticks + 1500
        await ticked(service, task, stop_at)
        service.stop()
        await task

    asyncio.run(scenario())
    assert not replies["bad"]["ok"] and "unstable" in replies["bad"]["error"]
    assert replies["status"]["model"]["name"] == "example-gated-arx-y"
    assert replies["good"]["ok"] and replies["good"]["model"] == "retuned"
    assert service.compensator.active.compiled.name == "retuned"
    y = offsets(records)
    assert np.all(np.abs(np.diff(y)) <= SLEW_UM + 1e-12)
    blending = [bool(r.status & Flag.BLENDING) for r in records]
    start = blending.index(True)
    assert sum(blending) == 120 and not blending[-1]
    new_output = records[-1].model_outputs["disp_y_um"]
    assert records[-1].offsets_um["Y"] == pytest.approx(-new_output)
    assert records[start + 200].model_outputs["disp_y_um"] != pytest.approx(
        records[start + 200].targets_um["Y"] * 0
    )


def test_connection_drop_is_survived(tmp_path):
    """A 15 s connection drop is bridged: the loop goes on, the driver reconnects with backoff, no signal faults."""
    drop = {"kind": "drop", "start_s": 300, "duration_s": 15}
    config = write_config(tmp_path, {"drivers": {"machine": {"settings": {"faults": [drop]}}}})
    service, records = run(config, 600.0)
    assert len(records) == 601
    counters = service.status()["counters"]
    assert counters["driver_faults"] == 1 and counters["reconnects"] == 1
    assert counters["signal_faults"] == 0 and counters["write_failures"] > 0
    assert records[310].status & Flag.DRIVER_DOWN and records[-1].status == Level.OK


def test_first_write_after_a_drop_is_within_one_slew_step(tmp_path):
    """While the PLC is unreachable the safety stage follows what it holds, so reconnecting never jumps the offset."""
    _, good = bad_and_good_models(tmp_path)
    fast = tmp_path / "fast.yaml"  # g2 = 400: the target outruns the 0.1 um/s slew limit
    fast.write_text(good.read_text().replace("gain: 1.6       # g2", "gain: 400       # g2"))
    drop = {"kind": "drop", "start_s": 150, "duration_s": 30}
    plc = {
        "type": "simulated",
        "settings": {"data": "bundled:example_spectrum.csv", "faults": [drop]},
    }
    config = write_config(
        tmp_path,
        {
            "model": str(fast),
            "drivers": {"machine": {"settings": {"start_s": 7200}}, "plc": plc},
            "outputs": {"Y": {"driver": "plc", "max_rate_um_per_s": 0.1}},
            "status": {"driver": "plc"},
        },
    )
    _, records = run(config, 300.0)
    written = np.array([r.offsets_um["Y"] for r in records if r.written])
    assert len(written) < len(records)  # some writes failed
    assert np.all(np.abs(np.diff(written)) <= 0.1 + 1e-12)
    # The target ran far ahead of the last written offset during the drop.
    assert abs(records[180].targets_um["Y"] - records[149].offsets_um["Y"]) > 5


def test_recordings_load_as_data_on_the_tick_grid(tmp_path):
    """The recorder's files load with compd's data loader at the period, with inputs, contributions and offsets."""
    config = write_config(tmp_path, {"recorder": {"enabled": True}})
    _, records = run(config, 600.0)
    (path,) = (config.state_dir / "records").glob("compd-*.csv")
    data = load_data(path)
    assert data.sample_time_s == 1.0 and len(data) == len(records) and not data.notes
    assert_allclose(data.column("offset.Y_um"), offsets(records))
    for column in ("T_spindle_degC", "model.disp_y_um.heating_difference", "status", "heartbeat"):
        assert data.has(column)


class _Watchdog:
    """Counts the sd_notify calls the service makes (the real notifier is tested on a socket)."""

    #: No spacing between pings (a real unit's is a quarter of WatchdogSec, in real time, which a
    #: virtual clock's back-to-back ticks would all fall within): every tick on time pings.
    watchdog_interval_s = 0.0

    def __init__(self) -> None:
        self.pings = 0

    def watchdog(self) -> bool:
        self.pings += 1
        return True

    def ready(self, status: str | None = None) -> bool:
        return True

    def status(self, text: str) -> bool:
        return True

    def stopping(self, status: str | None = None) -> bool:
        return True


def test_watchdog_is_pinged_only_for_ticks_that_keep_their_period(tmp_path):
    """A tick that takes longer than the period (a stalled loop) does not ping systemd's watchdog."""
    config = write_config(tmp_path)
    clock = VirtualClock()
    notifier = _Watchdog()
    service = Service(config, clock=clock, control=False, notifier=notifier)
    tick = service.compensator.tick

    async def slow_every_tenth(t_s: float):
        record = await tick(t_s)
        if service.compensator.counters.ticks % 10 == 0:
            clock.advance(1.5)  # this tick overran its 1 s period
        return record

    service.compensator.tick = slow_every_tenth
    run(config, 99.0, service=service)
    ticks = service.compensator.counters.ticks
    assert 0 < notifier.pings == ticks - ticks // 10
