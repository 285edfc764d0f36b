"""A PLC that answers every write with an exception: one fault episode, a status that says so, no flipping.

A real pymodbus server on 127.0.0.1 whose offset register is read-only (every
write there is answered with a Modbus exception), then restarted on the same
port with it writable: the daemon runs on virtual time against it.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from structlog.testing import capture_logs

from compd.service.daemon import Service
from compd.service.loop.clock import VirtualClock
from compd.service.loop.safety import Flag, Level
from compd.service.loop.statusview import health_problems
from tests.drivers.modbus_server import ServerThread, free_port
from tests.service.daemon_setup import ticked, write_config

OFFSET_REGISTER = 150


def device(*, refuse_writes: bool) -> SimDevice:
    """The machine's inputs (25.00 degC, 22.00 degC, 3000 rpm); holding 150-159 read-only if ``refuse_writes``."""
    inputs = [0] * 16
    inputs[10:13] = [2500, 2200, 3000]
    return SimDevice(
        id=1,
        simdata=(
            [SimData(0, count=16, values=False, datatype=DataType.BITS)],
            [SimData(0, count=16, values=False, datatype=DataType.BITS)],
            [
                SimData(0, count=OFFSET_REGISTER, values=0, datatype=DataType.REGISTERS),
                SimData(
                    OFFSET_REGISTER,
                    count=10,
                    values=0,
                    datatype=DataType.REGISTERS,
                    readonly=refuse_writes,
                ),
            ],
            [SimData(0, values=inputs, datatype=DataType.REGISTERS)],
        ),
    )


def server(port: int, *, refuse_writes: bool) -> ServerThread:
    return ServerThread(
        lambda: ModbusTcpServer(device(refuse_writes=refuse_writes), address=("127.0.0.1", port))
    )


def config_doc(port: int, *, readback: bool) -> dict[str, Any]:
    signal = {"driver": "plc", "unit": "degC", "scale": 0.01, "type": "int"}
    return {
        "schema": "compd.config/1",
        "model": "bundled:example_gated_arx.yaml",
        "period_s": 1.0,
        "drivers": {"plc": {"type": "modbus", "settings": {"host": "127.0.0.1", "port": port}}},
        "signals": {
            "T_spindle_degC": signal | {"address": "input:10:int16"},
            "T_shopfloor_degC": signal | {"address": "input:11:int16"},
            "spindle_speed_rpm": {"driver": "plc", "address": "input:12:uint16", "unit": "rpm"},
        },
        "outputs": {
            "Y": {
                "model_output": "disp_y_um",
                "driver": "plc",
                "address": f"holding:{OFFSET_REGISTER}:int16",
                "encoding": {"type": "int", "scale": 10},
                "readback": readback,
                "max_offset_um": 50,
                "max_rate_um_per_s": 1,
            }
        },
        "status": {
            "driver": "plc",
            "status_address": "holding:20",
            "heartbeat_address": "holding:21",
        },
    }


@pytest.mark.parametrize("readback", [False, True], ids=["acknowledged", "read-back"])
def test_refused_writes_are_one_episode_and_a_steady_status_that_is_not_ok(
    tmp_path: Path, readback: bool
):
    """Writes refused 20 ticks: ERROR once, a steady 'driver down' status word, healthz failing; INFO when accepted."""
    port = free_port()
    refusing = server(port, refuse_writes=True)
    refusing.start()
    config = write_config(tmp_path, doc=config_doc(port, readback=readback))
    service = Service(config, clock=VirtualClock(), control=False)
    words: list[int] = []
    service.subscribe(lambda record: words.append(record.status))
    link = service.links["plc"]
    seen: dict[str, Any] = {}

    async def scenario() -> None:
        running = asyncio.ensure_future(service.run(duration_s=None))
        await ticked(service, running, 20)
        seen["state"] = link.state
        seen["status"] = service.status()["drivers"]  # compd status's reply
        seen["problems"] = health_problems(
            service.compensator, service.links, service.timing, clock=service.clock, period_s=1.0
        )
        refusing.stop()
        accepting = server(port, refuse_writes=False)
        accepting.start()
        try:
            while link.refusing_writes and not running.done():
                await asyncio.sleep(0)
            await ticked(service, running, service.compensator.counters.ticks + 3)
            seen["after"] = (link.state, service.compensator.last.status)
        finally:
            service.stop()
            await running
            accepting.stop()

    with capture_logs() as logs:
        asyncio.run(scenario())
    errors = [e["event"] for e in logs if e["log_level"] == "error"]
    assert len(errors) == len(set(errors)), errors  # no ERROR line twice in one episode
    refused = [e for e in logs if e["event"] == "driver write refused"]
    assert len(refused) == 1 and refused[0]["log_level"] == "error"
    assert "exception code" in refused[0]["error"]
    assert [e["log_level"] for e in logs if e["event"] == "driver write accepted again"] == ["info"]
    assert seen["state"] == "refusing writes" and seen["status"] == {"plc": "refusing writes"}
    assert any("refusing writes" in p for p in seen["problems"])
    refused_words = set(words[1:20])  # the first tick learns it
    assert len(refused_words) == 1
    (word,) = refused_words
    assert word & Flag.DRIVER_DOWN and Level(word & 0b11) is not Level.OK
    state, last_word = seen["after"]
    assert state == "up" and not last_word & Flag.DRIVER_DOWN
