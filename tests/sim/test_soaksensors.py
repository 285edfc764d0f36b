"""The soak's sensor faults (:mod:`compd.sim.soaksensors`): each variant the machine's own fault, struck as it runs."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest

from compd.sim.plc.build import build_machine
from compd.sim.soak import soak_config
from compd.sim.soakfaults import SENSOR_KINDS, VARIANTS, Fault
from compd.sim.soaksensors import SensorEpisode, excess_lines, machine_fault, model_inputs

SPINDLE = "input:0:int16"  # T_spindle_degC at 0.01 degC


class Published:
    """A PLC server that keeps what the machine publishes."""

    def __init__(self) -> None:
        self.raw: dict[str, float] = {}

    def publish(self, values: dict[str, float]) -> None:
        self.raw = dict(values)

    async def start(self) -> None:
        pass

    async def stop(self) -> None:
        pass


@pytest.mark.parametrize(
    ("kind", "variant", "machine_kind", "value"),
    [
        ("sensor_offset", "+15", "offset", 15.0),
        ("sensor_offset", "-25", "offset", -25.0),
        ("glitch", "60", "value", 60.0),
        ("stuck", "", "stuck", None),
        ("wire_break", "high", "value", 327.67),
        ("wire_break", "low", "value", -200.0),
        ("wire_break", "nan", "nan", None),
    ],
)
def test_each_sensor_fault_is_the_simulated_machines_own_fault(
    kind: str, variant: str, machine_kind: str, value: float | None
):
    """Offset +15/-25, glitch 60, stuck, wire break 327.67/-200/NaN: the machine's own fault on the signal."""
    doc = machine_fault(Fault(0.0, kind, variant, 40.0), "T_spindle_degC", 120.0)
    assert (doc.kind, doc.value, doc.signal, doc.at_s, doc.duration_s) == (
        machine_kind, value, "T_spindle_degC", 120.0, 40.0,
    )  # fmt: skip


def test_every_sensor_variant_the_draw_can_make_has_a_machine_fault():
    """No variant of a sensor kind is left without its machine fault."""
    for kind in SENSOR_KINDS:
        for variant in VARIANTS[kind]:
            machine_fault(Fault(0.0, kind, variant, 60.0), "T_ambient_degC", 0.0)


def test_a_fault_injected_while_the_machine_runs_reaches_the_reading_and_ends(tmp_path: Path):
    """+15 degC injected at 600 s for 100 s: the next published reading is 15 degC up, and it is back at 700 s."""
    config = soak_config(tmp_path, hours=0.5, seed=3)
    assert model_inputs(config) == [
        "T_spindle_degC", "T_headstock_degC", "T_column_front_degC", "T_ambient_degC",
    ]  # fmt: skip
    machine = build_machine(config)
    server = machine.servers["plc"] = Published()

    async def main() -> None:
        await machine.advance_to(600.0)
        offset = Fault(600.0, "sensor_offset", "+15", 100.0)
        machine.inject(machine_fault(offset, "T_spindle_degC", machine.now_s))
        for t_s, expected_degC in ((601.0, 15.0), (699.0, 15.0), (700.0, 0.0)):
            await machine.advance_to(t_s)
            truth = machine.row["T_spindle_degC"]
            assert server.raw[SPINDLE] * 0.01 == pytest.approx(truth + expected_degC), t_s

    asyncio.run(main())


def test_the_verdict_has_one_line_per_sensor_fault_with_its_excess():
    """Per fault: stand-in time, window maximum, the fault-free run's, the excess, other faults; then the summary."""
    episodes = [
        SensorEpisode("sensor_offset", "+15", "T_spindle_degC", 300.0, 100.0, 12.5, 2.0, 130.0),
        SensorEpisode("stuck", "", "T_headstock_degC", 600.0, 80.0, 3.0, 3.25, 0.0, ("kill",)),
    ]
    assert episodes[0].window_s == (300.0, 1000.0) and episodes[1].excess_um == -0.25
    assert episodes[0].alone and not episodes[1].alone
    header, first, second, summary, alone = excess_lines(episodes)
    assert "stand-in" in header and "excess" in header
    assert first.startswith("sensor_offset +15") and first.endswith("+10.50") and " 130s " in first
    assert second.startswith("stuck ") and second.endswith("-0.25   also: kill")
    assert summary == (
        "excess over the fault-free run: median +5.12 um, largest +10.50 um (2 sensor faults)"
    )
    assert alone.endswith("in the window: median +10.50 um, largest +10.50 um (1 sensor faults)")
    no_reference = SensorEpisode("glitch", "60", "T_ambient_degC", 0.0, 40.0, 1.0)
    assert math.isnan(no_reference.excess_um) and len(excess_lines([no_reference])) == 2
