"""The Modbus driver over RTU: a pymodbus serial server on the far end of a socat pty pair."""

from __future__ import annotations

import asyncio
import re
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus.server import ModbusSerialServer

from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings
from compd.errors import DriverProtocolError, DriverTimeoutError

from .contract import ContractSetup, DriverContract
from .modbus_server import INPUTS, READONLY_START, ServerThread, make_device


@pytest.fixture
def pty_pair(tmp_path) -> Iterator[tuple[str, str, subprocess.Popen]]:
    """Two linked pseudo-terminals from socat: (compd's end, the device's end, the socat process)."""
    if shutil.which("socat") is None:
        pytest.skip("socat not installed: run .ci/install-system-packages")
    ours, theirs = tmp_path / "compd-tty", tmp_path / "plc-tty"
    proc = subprocess.Popen(
        ["socat", f"pty,raw,echo=0,link={ours}", f"pty,raw,echo=0,link={theirs}"],
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60  # a hang guard: socat starts slowly on a busy host
    while not (ours.exists() and theirs.exists()):
        assert time.monotonic() < deadline, "socat did not create the pty pair"
        time.sleep(0.02)
    yield str(ours), str(theirs), proc
    proc.terminate()
    proc.wait(5)


@pytest.fixture
def rtu(pty_pair) -> Iterator[tuple[ModbusDriver, subprocess.Popen]]:
    """A Modbus RTU device on the far end of a pty pair and a driver on the near end."""
    ours, theirs, proc = pty_pair
    thread = ServerThread(lambda: ModbusSerialServer(make_device(), port=theirs, baudrate=115200))
    thread.start()
    settings = ModbusSettings(
        transport="rtu", serial_port=ours, baudrate=115200, request_timeout_s=0.3
    )
    yield ModbusDriver(settings, now=time.monotonic, base_dir=Path()), proc
    thread.stop()


def test_rtu_read_write_and_refusal(rtu):
    """Over RTU the same addresses read and write; refused writes and absent devices are driver errors."""
    driver, _ = rtu
    written = {"holding:10:int32": -12345.0, "coil:2": 1.0}

    async def scenario() -> dict[str, float]:
        await driver.open()
        await driver.write(written)
        values = await driver.read([*INPUTS, *written])
        with pytest.raises(DriverProtocolError, match="refused"):
            await driver.write({f"holding:{READONLY_START}": 1.0})
        # pymodbus's serial server answers for absent ids with "device failure";
        # a real bus stays silent (a timeout). Either is a DriverError.
        with pytest.raises((DriverProtocolError, DriverTimeoutError)):
            await driver.read(["holding:0:device=9"])
        await driver.close()
        return values

    assert asyncio.run(scenario()) == pytest.approx({**INPUTS, **written})


class TestModbusRtuContract(DriverContract):
    """The Modbus driver over RTU (socat pty pair) passes the driver contract."""

    @pytest.fixture
    def setup(self, rtu) -> ContractSetup:
        driver, socat = rtu
        return ContractSetup(
            driver=driver,
            readable=("input:0:int16", "input:2:float32:word=little", "discrete:0"),
            writable="holding:30:int32",
            missing="holding:9000",
            break_connection=socat.kill,
        )


def test_mbpoll_reads_over_rtu_what_compd_wrote(rtu, pty_pair):
    """After compd writes over RTU and closes, Debian's mbpoll reads the same value on the same line."""
    if shutil.which("mbpoll") is None:
        pytest.skip("mbpoll not installed: run .ci/install-system-packages")
    driver, _ = rtu

    async def write() -> None:
        await driver.open()
        await driver.write({"holding:20:int32": -4321.0})
        await driver.close()

    asyncio.run(write())
    line = ["-m", "rtu", "-b", "115200", "-P", "none", "-o", "2"]
    out = subprocess.run(
        ["mbpoll", *line, "-1", "-t", "4:int", "-B", "-r", "21", pty_pair[0]],
        capture_output=True,
        text=True,
        timeout=10,
        check=True,
    ).stdout
    assert re.search(r"^\[21\]:\s*-4321$", out, re.MULTILINE), out
