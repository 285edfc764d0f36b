"""The soak's faults (:mod:`compd.sim.soakfaults`): a seeded draw of every kind, bad files and replies that are bad."""

from __future__ import annotations

import asyncio
import itertools
import json
import time
from pathlib import Path

import pytest

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import CompdError, DriverError
from compd.files.modelfile import load_model
from compd.files.yamlplace import resolve_path
from compd.service.control.modelload import slot_from_bytes
from compd.service.store.state import STATE_FILE, SavedState, StateError, load_state
from compd.sim.plc.modbus import ModbusPlcServer
from compd.sim.soak import soak_config
from compd.sim.soakfaults import (
    BAD_NUMBERS,
    FAULT_KINDS,
    VARIANTS,
    bad_models,
    corrupt_state,
    draw_faults,
    malformed_replies,
)

from ..drivers.modbus_server import free_port


def test_the_fault_draw_covers_every_kind_first_and_is_seeded():
    """The first faults are one of each kind; the same seed draws the same faults, 2-6 min apart."""
    faults = draw_faults(8 * 3600, 1)
    assert {f.kind for f in faults[: len(FAULT_KINDS)]} == set(FAULT_KINDS)
    assert faults == draw_faults(8 * 3600, 1) != draw_faults(8 * 3600, 2)
    assert all(120 <= b.at_s - a.at_s <= 360 for a, b in itertools.pairwise(faults))


def test_every_bad_model_is_refused_by_the_daemons_check(tmp_path: Path):
    """Gain 1e308, nk 10^6, a pole at 1.2 and garbage bytes, made from the bundled model, are each refused."""
    config = soak_config(tmp_path, hours=1, seed=1)
    bad = bad_models(config.model_path.read_bytes())
    assert set(bad) == {"gain_1e308", "nk_1e6", "unstable", "garbage"}
    for name, raw in bad.items():
        with pytest.raises(CompdError):
            slot_from_bytes(config, raw, name, 0.0)


@pytest.mark.parametrize("variant", VARIANTS["malformed"])
def test_the_plcs_malformed_replies_are_driver_errors_and_the_next_true_reply_reads(variant: str):
    """With every reply rewritten as ``variant`` compd's Modbus driver raises DriverError; unset, it reads again."""
    inputs = {"input:0:int16": 1234.0, "input:1:int16": -5.0}

    async def main() -> None:
        port = free_port()
        settings = ModbusSettings(host="127.0.0.1", port=port, request_timeout_s=0.3)
        server = ModbusPlcServer(
            settings, inputs=list(inputs), outputs=[], on_write=lambda *_: None, base_dir=Path()
        )
        await server.start()
        server.publish(inputs)
        driver = ModbusDriver(settings, now=time.monotonic, base_dir=Path())
        try:
            await driver.open()
            server.rewrite_reply = malformed_replies(variant, 0.5, share=1.0)
            with pytest.raises(DriverError):
                await driver.read(list(inputs))
            await driver.close()
            server.rewrite_reply = None
            await driver.open()
            assert await driver.read(list(inputs)) == inputs
        finally:
            await driver.close()
            await server.stop()

    asyncio.run(main())


@pytest.mark.parametrize("variant", BAD_NUMBERS)
def test_a_bad_number_in_the_state_file_is_written_as_text_and_refused_by_its_key(
    tmp_path: Path, variant: str
):
    """Ticks of 1e400, Infinity, -Infinity or 5,000 digits, a NaN save time: the state is refused, naming the key."""
    model = load_model(resolve_path("bundled:simulated_model.yaml", Path(".")))
    compiled = model.compile()
    state = compiled.steady_state({name: 21.0 for name in model.model.signals()})
    saved = SavedState(model.sha256, compiled.name, 1000.0, state, {"Z": 1.5}, 42)
    key, text = BAD_NUMBERS[variant]
    corrupt = corrupt_state(json.dumps(saved.to_dict()).encode(), variant)
    assert f'"{key}": {text}'.encode() in corrupt
    (tmp_path / STATE_FILE).write_bytes(corrupt)
    with pytest.raises(StateError, match=key):
        load_state(tmp_path)
