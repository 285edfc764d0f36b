"""A model failing while the daemon runs is unloaded, flagged and logged once; no crash, no restart into it."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from structlog.testing import capture_logs

from compd.service.config.docs import MAX_SIGNALS
from compd.service.control.modelload import load_request
from compd.service.control.socket import request
from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import SIGNAL_BIT0, Level, mismatch_bit, model_fault_bit
from compd.service.store.state import install_model_bytes, installed_model

from .daemon_setup import run, short_socket, ticked, write_config
from .test_service import SLEW_UM, bad_and_good_models, offsets

CONFIG_MODEL = "example-gated-arx-y"


def faulted(record: TickRecord) -> bool:
    bit = model_fault_bit(len(record.health))
    return bit is not None and bool(record.status & (1 << bit))


def run_with_load(
    tmp_path: Path, on_tick: Callable[[Service, TickRecord], None], ticks_after: int = 800
) -> tuple[Service, list[TickRecord], dict[str, Any], list[dict[str, Any]]]:
    """Run the simulated daemon; after 100 ticks load the retuned model; stop ``ticks_after`` ticks after the reply.

    Counted from the reply, not from the start: on virtual time the ticks
    race ahead while the daemon checks the model in its worker thread.
    """
    _, good = bad_and_good_models(tmp_path)
    socket = short_socket()
    config = write_config(
        tmp_path,
        {
            "drivers": {"machine": {"settings": {"start_s": 7200}}},
            "control_socket": str(socket),
            "blend_s": 10,
        },
    )
    service = Service(config, clock=VirtualClock(), control=True)
    records: list[TickRecord] = []

    def tick(record: TickRecord) -> None:
        records.append(record)
        on_tick(service, record)

    service.subscribe(tick)
    replies: dict[str, Any] = {}

    async def scenario() -> None:
        task = asyncio.create_task(service.run())
        counters = service.compensator.counters
        await ticked(service, task, 100)
        # A hang guard, not a bound: on virtual time the loop ticks back to back and shares the
        # interpreter with the model check in its worker thread; under the suite's load the
        # reply once took over the client's default 5 s.
        started = time.perf_counter()
        replies["load"] = await request(
            socket, load_request(good.read_bytes(), good), timeout_s=120.0
        )
        replies["took_s"] = time.perf_counter() - started
        stop_at = counters.ticks + ticks_after
        await ticked(service, task, stop_at)
        service.stop()
        await task

    with capture_logs() as logs:
        asyncio.run(scenario())
    return service, records, replies, logs


def test_a_model_that_fails_while_running_is_unloaded_and_the_previous_restored(tmp_path):
    """A loaded model raising mid-shift is unloaded, the config's restored (fault bit set), started next time."""
    failed_at: list[int] = []

    def fail_once_blended(service: Service, record: TickRecord) -> None:
        comp = service.compensator
        if comp.active.compiled.name == "retuned" and comp.previous is None and not failed_at:
            failed_at.append(comp.counters.ticks)

            def overflow(signals: Any) -> np.ndarray:
                raise FloatingPointError("overflow in matmul")

            comp.active.runner.step = overflow  # type: ignore[union-attr, method-assign]

    service, records, replies, logs = run_with_load(tmp_path, fail_once_blended)
    assert replies["load"]["ok"] and failed_at
    assert len(records) >= 900  # the daemon went on to the end
    assert service.compensator.active.compiled.name == CONFIG_MODEL
    assert service.compensator.counters.model_failures == 1
    failing = records[failed_at[0]]  # the tick after the fault was injected
    assert faulted(failing) and failing.status & 0b11 == Level.FAULTED
    assert not faulted(records[-1]) and np.isfinite(records[-1].model_outputs["disp_y_um"])
    assert np.all(np.abs(np.diff(offsets(records))) <= SLEW_UM + 1e-12)
    errors = [e for e in logs if e["log_level"] == "error"]
    assert [e["event"] for e in errors] == ["model failed and was unloaded"]
    assert errors[0]["model"] == "retuned" and errors[0]["restored"] == CONFIG_MODEL
    assert service.status()["counters"]["model_failures"] == 1
    # The failed model was installed by the load; it is no longer what a restart picks.
    assert installed_model(service.config.state_dir) is None
    restarted = Service(service.config, clock=VirtualClock(), control=False)
    assert restarted.compensator.active.compiled.name == CONFIG_MODEL


def test_a_new_model_that_cannot_start_is_dropped_and_the_running_one_goes_on(
    tmp_path, monkeypatch
):
    """A model whose warm start raises at the switch is dropped and un-installed; the running model never stops."""

    def broken_handover(*args: Any, **kwargs: Any) -> Any:
        raise np.linalg.LinAlgError("singular matrix")

    monkeypatch.setattr("compd.service.loop.slots.handover_state", broken_handover)
    service, records, replies, logs = run_with_load(tmp_path, lambda s, r: None, ticks_after=200)
    assert replies["load"]["ok"]  # accepted: it failed only when the loop started it
    assert len(records) >= 300 and service.compensator.active.compiled.name == CONFIG_MODEL
    assert service.compensator.counters.model_failures == 1
    assert sum(faulted(r) for r in records) >= 1 and not faulted(records[-1])
    assert [e["event"] for e in logs if e["log_level"] == "error"] == [
        "model failed and was unloaded"
    ]
    assert installed_model(service.config.state_dir) is None


def test_a_non_finite_model_output_sets_the_status_bit_and_is_logged_once(tmp_path):
    """A model whose state turns NaN is flagged (fault bit, level faulted), logged once, restarted from its inputs."""
    config = write_config(tmp_path, {"drivers": {"machine": {"settings": {"start_s": 7200}}}})
    service = Service(config, clock=VirtualClock(), control=False)

    def poison(record: TickRecord) -> None:
        if service.compensator.counters.ticks == 100:
            for z in service.compensator.active.runner._z:  # type: ignore[union-attr]
                z[:] = [np.nan] * len(z)

    records: list[TickRecord] = []
    service.subscribe(lambda record: (records.append(record), poison(record)))
    with capture_logs() as logs:
        asyncio.run(service.run(duration_s=300.0))
    flagged = [i for i, r in enumerate(records) if faulted(r)]
    assert flagged and flagged[0] == 100  # the tick after the state went NaN
    assert all(records[i].status & 0b11 == Level.FAULTED for i in flagged)
    assert not faulted(records[-1]) and len(records) == 301
    assert np.all(np.abs(np.diff(offsets(records))) <= SLEW_UM + 1e-12)
    events = [(e["log_level"], e["event"]) for e in logs if "model" in e["event"]]
    assert events == [
        ("error", "model fault: the axes hold their offsets"),
        ("info", "model outputs are finite again"),
    ]


def test_an_installed_model_refused_at_start_falls_back_to_the_configs(tmp_path):
    """An installed model that no longer passes the checks is logged and un-installed; the config's model starts."""
    config = write_config(tmp_path)
    text = config.model_path.read_text().replace("gain: 1.0       # g2", "gain: 1.0e+308  # g2")
    install_model_bytes(config.state_dir, text.encode())
    assert installed_model(config.state_dir) is not None
    with capture_logs() as logs:
        service, records = run(config, 10.0)
    assert service.compensator.active.compiled.name == CONFIG_MODEL and len(records) == 11
    refusal = next(e for e in logs if e["log_level"] == "error")
    assert refusal["event"] == "the installed model is refused; starting with the config's model"
    assert "static gain" in refusal["error"]
    assert installed_model(config.state_dir) is None


def test_an_installed_model_that_cannot_be_read_is_set_aside_and_the_configs_starts(tmp_path):
    """An installed model with a 5,000-digit gain: set aside (kept), one ERROR naming it; the config's starts."""
    config = write_config(tmp_path)
    text = config.model_path.read_text().replace("gain: 1.0       # g2", "gain: " + "9" * 5000)
    installed = install_model_bytes(config.state_dir, text.encode())
    with capture_logs() as logs:
        service, records = run(config, 10.0)
    assert service.compensator.active.compiled.name == CONFIG_MODEL and len(records) == 11
    (error,) = [e for e in logs if e["log_level"] == "error"]
    (aside,) = installed.parent.glob(f"{installed.name}.corrupt-*")
    assert error["event"] == (
        "the installed model cannot be read: set aside; starting with the config's model"
    )
    assert error["installed"] == str(installed) and error["set_aside_as"] == str(aside)
    assert ".gain): " in error["reason"] and "an integer of 5000 digits" in error["reason"]
    assert aside.read_text() == text and not installed.exists()
    assert installed_model(config.state_dir) is None


def test_an_installed_model_whose_bytes_changed_is_set_aside(tmp_path):
    """An installed model whose bytes no longer match the sha256 it is named by (bit rot) is not started."""
    config = write_config(tmp_path)
    text = config.model_path.read_text().replace("gain: 1.0       # g2", "gain: 1.1       # g2")
    installed = install_model_bytes(config.state_dir, text.encode())
    installed.write_text(text.replace("gain: 1.1", "gain: 9.1"))
    with capture_logs() as logs:
        service, _ = run(config, 2.0)
    assert service.compensator.active.compiled.name == CONFIG_MODEL
    (error,) = [e for e in logs if e["log_level"] == "error"]
    assert "its bytes are not those installed" in error["reason"]
    assert installed_model(config.state_dir) is None


def test_a_file_outside_the_state_directory_named_as_installed_is_never_renamed(tmp_path):
    """current-model naming a file elsewhere that is no model: the config's model starts, that file stays put."""
    config = write_config(tmp_path)
    elsewhere = tmp_path / "not-a-model.yaml"
    elsewhere.write_text("schema: compd.config/1\n")
    config.state_dir.mkdir(parents=True, exist_ok=True)
    (config.state_dir / "current-model").write_text(f"{elsewhere}\n")
    with capture_logs() as logs:
        service, _ = run(config, 2.0)
    assert service.compensator.active.compiled.name == CONFIG_MODEL
    (error,) = [e for e in logs if e["log_level"] == "error"]
    assert error["event"] == "the installed model cannot be read; starting with the config's model"
    assert error["set_aside_as"] is None and "so left where it is" in error["reason"]
    assert elsewhere.read_text() == "schema: compd.config/1\n"


def test_a_current_model_file_that_is_not_text_starts_the_configs_model(tmp_path):
    """current-model holding bytes that are not UTF-8 (a corrupt card): the config's model starts, no traceback."""
    config = write_config(tmp_path)
    config.state_dir.mkdir(parents=True, exist_ok=True)
    (config.state_dir / "current-model").write_bytes(b"\xff\xfe models/x.yaml\n")
    (config.state_dir / "previous-model").write_bytes(b"\xff\n")
    assert installed_model(config.state_dir) is None
    service, records = run(config, 2.0)
    assert service.compensator.active.compiled.name == CONFIG_MODEL and len(records) == 3


def test_the_model_fault_bit_follows_the_signal_and_mismatch_bits():
    """The model-fault bit is the one after the readback-mismatch bit, itself after the signals'; none past bit 31."""
    assert model_fault_bit(3) == mismatch_bit(3) + 1 == SIGNAL_BIT0 + 4
    assert model_fault_bit(6) == 15  # a uint16 status word holds it for up to 6 signals
    assert model_fault_bit(MAX_SIGNALS) is None
