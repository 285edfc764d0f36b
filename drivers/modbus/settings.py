"""``drivers.<name>.settings`` of a ``type: modbus`` driver: TCP or RTU, the device, timeouts."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from compd.drivers.endpoints import Endpoint, serial_endpoint, tcp_endpoint


class ModbusSettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: modbus`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    transport: Literal["tcp", "rtu"] = "tcp"
    host: str | None = Field(default=None, description="tcp: PLC host name or IP")
    port: int = Field(default=502, ge=1, le=65535, description="tcp: port")
    serial_port: str | None = Field(default=None, description="rtu: e.g. /dev/ttyUSB0")
    baudrate: int = Field(default=19200, gt=0)
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    device_id: int = Field(default=1, ge=0, le=247, description="default device (unit) id")
    unit_ids: Literal["shared", "separate"] = Field(
        default="shared",
        description=(
            "tcp: 'separate' when the server routes each unit id to its own device (a gateway "
            "to a serial bus); 'shared': many servers ignore the unit id, so the overlap checks "
            "take every unit id on this host:port for the same device"
        ),
    )
    request_timeout_s: float = Field(default=0.5, gt=0, description="per request")
    max_registers_per_request: int = Field(default=125, ge=1, le=125)

    def endpoint(self) -> Endpoint:
        """The host and port, or the serial line, this driver reaches."""
        if self.transport == "tcp":
            assert self.host is not None  # checked below
            return tcp_endpoint("modbus", self.host, self.port)
        assert self.serial_port is not None
        return serial_endpoint(self.serial_port)

    @model_validator(mode="after")
    def _transport_needs(self) -> ModbusSettings:
        if self.transport == "tcp" and not self.host:
            raise ValueError("transport 'tcp' needs 'host'")
        if self.transport == "rtu" and not self.serial_port:
            raise ValueError("transport 'rtu' needs 'serial_port'")
        return self
