"""The Modbus TCP side of a Profibus gateway: the DP input area in input registers, the output in holding.

Two bytes a register, first byte high. One request reads the whole input
area and one writes the whole output area, so a tick's values come from one
gateway cycle and the PLC sees one consistent output image. The requests,
the connection and the translation of pymodbus errors are the Modbus
driver's own, through its public single-request methods
(:meth:`~compd.drivers.modbus.driver.ModbusDriver.read_span`,
:meth:`~compd.drivers.modbus.driver.ModbusDriver.write_registers`).
"""

from __future__ import annotations

import time
from pathlib import Path

from compd.drivers.gateway.settings import GatewaySettings
from compd.drivers.gateway.status import StatusWatch
from compd.drivers.modbus.driver import ModbusDriver
from compd.drivers.modbus.settings import ModbusSettings


class ModbusTransport:
    """The image as input and holding registers; reuses the Modbus driver's requests and errors."""

    def __init__(self, settings: GatewaySettings, watch: StatusWatch) -> None:
        self.settings = settings
        self.watch = watch
        self.where = f"{settings.host}:{settings.port}"
        self._modbus = ModbusDriver(
            ModbusSettings(
                host=settings.host,
                port=settings.port,
                device_id=settings.device_id,
                request_timeout_s=settings.request_timeout_s,
            ),
            now=time.monotonic,
            base_dir=Path(),
        )

    async def open(self) -> None:
        await self._modbus.open()

    async def read_input(self) -> tuple[bytes, frozenset[int] | None]:
        s = self.settings
        registers = await self._modbus.read_span(
            "input", s.input_register, s.input_bytes // 2, device=s.device_id
        )
        image = b"".join(int(r).to_bytes(2, "big") for r in registers[: s.input_bytes // 2])
        if s.status is not None:
            self.watch.observe(image[s.status.offset], time.monotonic())
        return image, None

    async def read_output(self) -> bytes:
        """The output area as the gateway holds it now (its holding registers)."""
        s = self.settings
        registers = await self._modbus.read_span(
            "holding", s.output_register, s.output_bytes // 2, device=s.device_id
        )
        return b"".join(int(r).to_bytes(2, "big") for r in registers[: s.output_bytes // 2])

    async def write_output(self, image: bytes) -> None:
        s = self.settings
        registers = [int.from_bytes(image[i : i + 2], "big") for i in range(0, len(image), 2)]
        last = s.output_register + len(registers) - 1
        await self._modbus.write_registers(
            s.output_register,
            registers,
            device=s.device_id,
            what=f"write output area (holding {s.output_register}..{last})",
        )

    async def close(self) -> None:
        await self._modbus.close()
