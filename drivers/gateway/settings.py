"""The settings of a ``type: profibus_gateway`` driver: the DP areas, the transport, the status byte.

Checked as they are read: each transport's limits (whole registers and one
request per area over Modbus TCP; at most four 8-byte PDOs per direction
over CANopen, one id per frame for raw CAN), and the status and live bits
inside their areas. See :mod:`compd.drivers.gateway.driver` for what they mean.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from compd.drivers.endpoints import Endpoint, can_endpoint, tcp_endpoint
from compd.drivers.gateway.image import MAX_AREA_BYTES
from compd.drivers.points import Order

#: Bytes a CAN frame (a PDO) carries.
FRAME_BYTES = 8
#: PDOs per direction in CANopen.
MAX_PDOS = 4
_MAX_READ_REGISTERS = 125  # Modbus limits: one request per area keeps an area consistent
_MAX_WRITE_REGISTERS = 123


class StatusSettings(BaseModel):
    """Where the gateway's status byte is in the input area, and its bits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    offset: int = Field(ge=0, description="byte offset in the input area")
    live_bit: int | None = Field(default=None, ge=0, le=7, description="toggles every cycle")
    ok_bit: int | None = Field(default=None, ge=0, le=7, description="set in data exchange")


class OutputLiveSettings(BaseModel):
    """compd's own live bit in the output area, toggled on every write."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    offset: int = Field(ge=0, description="byte offset in the output area")
    bit: int = Field(ge=0, le=7)


class GatewaySettings(BaseModel):
    """``drivers.<name>.settings`` of a ``type: profibus_gateway`` driver."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    transport: Literal["modbus_tcp", "can"] = "modbus_tcp"
    input_bytes: int = Field(ge=1, le=MAX_AREA_BYTES, description="size of the DP input area")
    output_bytes: int = Field(default=0, ge=0, le=MAX_AREA_BYTES, description="DP output area")
    byte_order: Order = Field(default="big", description="default for addresses without byte=")
    word_order: Order = Field(default="big", description="default for addresses without word=")
    request_timeout_s: float = Field(default=0.5, gt=0, description="per request / SYNC cycle")
    # modbus_tcp
    host: str | None = None
    port: int = Field(default=502, ge=1, le=65535)
    device_id: int = Field(default=1, ge=0, le=247)
    input_register: int = Field(default=0, ge=0, le=65535)
    output_register: int = Field(default=0, ge=0, le=65535)
    # can
    interface: str = Field(default="socketcan", description="python-can interface")
    channel: str | None = Field(default=None, description="e.g. can0, vcan0")
    bitrate: int | None = Field(default=None, gt=0)
    protocol: Literal["canopen", "raw"] = "canopen"
    node_id: int = Field(default=1, ge=1, le=127)
    sync: bool = False
    input_ids: tuple[int, ...] = ()
    output_ids: tuple[int, ...] = ()
    stale_s: float = Field(default=0.5, gt=0, description="older frames are stale")
    frame_timeout_s: float = Field(default=1.0, gt=0, description="no frame at all: timeout")
    # status
    status: StatusSettings | None = None
    live_timeout_s: float = Field(default=1.0, gt=0)
    output_live: OutputLiveSettings | None = None

    @model_validator(mode="after")
    def _consistent(self) -> GatewaySettings:
        if self.transport == "modbus_tcp":
            self._check_modbus()
        else:
            self._check_can()
        if self.status is not None:
            if self.status.offset >= self.input_bytes:
                raise ValueError(f"status.offset must be below input_bytes ({self.input_bytes})")
            if self.status.live_bit is not None and self.status.live_bit == self.status.ok_bit:
                raise ValueError("status.live_bit and status.ok_bit must differ")
        if self.output_live is not None and self.output_live.offset >= self.output_bytes:
            raise ValueError(f"output_live.offset must be below output_bytes ({self.output_bytes})")
        return self

    def _check_modbus(self) -> None:
        if not self.host:
            raise ValueError("transport 'modbus_tcp' needs 'host'")
        for name, size, limit in (
            ("input_bytes", self.input_bytes, _MAX_READ_REGISTERS),
            ("output_bytes", self.output_bytes, _MAX_WRITE_REGISTERS),
        ):
            if size % 2 or size > 2 * limit:
                raise ValueError(
                    f"over modbus_tcp {name} must be even and at most {2 * limit} "
                    "(whole registers, one request per area)"
                )
        if self.input_register + self.input_bytes // 2 > 65536:
            raise ValueError("the input area runs past input register 65535")
        if self.output_register + self.output_bytes // 2 > 65536:
            raise ValueError("the output area runs past holding register 65535")

    def _check_can(self) -> None:
        if not self.channel:
            raise ValueError("transport 'can' needs 'channel' (e.g. can0, vcan0)")
        n_in, n_out = self.frames("in"), self.frames("out")
        if self.protocol == "canopen":
            if max(n_in, n_out) > MAX_PDOS:
                raise ValueError(
                    f"CANopen carries at most {MAX_PDOS} PDOs of 8 bytes per direction: "
                    f"input_bytes and output_bytes must be at most {MAX_PDOS * FRAME_BYTES}"
                )
            if self.input_ids or self.output_ids:
                raise ValueError(
                    "input_ids/output_ids are for protocol 'raw'; canopen uses node_id"
                )
            return
        for name, ids, needed in (
            ("input_ids", self.input_ids, n_in),
            ("output_ids", self.output_ids, n_out),
        ):
            if len(ids) != needed:
                raise ValueError(
                    f"protocol 'raw' needs {needed} {name} (one 8-byte frame per 8 bytes of area)"
                )
            if any(not 0 < i <= 0x7FF for i in ids):
                raise ValueError(f"{name} must be 11-bit CAN ids 0x001..0x7FF")
        if len(set(self.input_ids) | set(self.output_ids)) != n_in + n_out:
            raise ValueError("input_ids and output_ids must all differ")

    def endpoint(self) -> Endpoint:
        """The gateway's host and port (Modbus, as a Modbus driver's), or its CAN bus."""
        if self.transport == "can":
            assert self.channel is not None  # checked above
            return can_endpoint(self.interface, self.channel)
        assert self.host is not None
        return tcp_endpoint("modbus", self.host, self.port)

    def image(self) -> tuple[object, ...]:
        """Which image of the endpoint: its first registers, or its node's (or raw) frame ids."""
        if self.transport == "modbus_tcp":
            return ("registers", self.input_register, self.output_register)
        return ("frames", self.can_ids("in"), self.can_ids("out"))

    def frames(self, area: Literal["in", "out"]) -> int:
        """CAN frames (PDOs) carrying an area."""
        size = self.input_bytes if area == "in" else self.output_bytes
        return -(-size // FRAME_BYTES)

    def can_ids(self, area: Literal["in", "out"]) -> tuple[int, ...]:
        """The CAN ids of an area's frames, in image order."""
        if self.protocol == "raw":
            return self.input_ids if area == "in" else self.output_ids
        base = 0x180 if area == "in" else 0x200
        return tuple(base + 0x100 * k + self.node_id for k in range(self.frames(area)))
