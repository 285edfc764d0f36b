"""An offset register holding a value outside the clamp is corrected, never followed: every encoding, every policy.

The service runs on virtual time against a real Modbus TCP PLC (the
simulated machine's server, as in :mod:`tests.service.test_readback`) whose
offset register holds, before the start or from one tick on, what no
compd ever wrote: 500 um or -3000 um in int16/int32 counts of 0.1 um, 1e30,
3e38, NaN or inf in a float32 or float64 register (in um). The clamp is
150 um. The PLC reports every value written to it; the tests judge those.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from compd.service.config.loading import Config, load_config
from compd.service.loop.compensator import TickRecord
from compd.service.loop.safety import Level
from tests.service.test_readback import MISMATCH_BIT, STEP_COUNTS, Plc, plc_config, run_against

MAX_UM = 150.0
#: The offset register per encoding, its config, and the raw values it holds (counts or um).
ENCODINGS: dict[str, tuple[dict[str, Any], list[float]]] = {
    "int16": ({"encoding": {"type": "int", "scale": 10}}, [5000, -30000, 32767]),
    "int32": ({"encoding": {"type": "int", "scale": 10}}, [5000, -30000, 2**31 - 1]),
    "float32": (
        {"encoding": {"type": "float", "scale": 1}},
        [500.0, 1e30, 3e38, -3e38, math.nan, math.inf],
    ),
    "float64": ({"encoding": {"type": "float", "scale": 1}}, [-3000.0, 1e300, math.nan, -math.inf]),
}
CASES = [(kind, raw) for kind, (_, raws) in ENCODINGS.items() for raw in raws]


def clamp_plc(directory: Path, kind: str, policy: str | None = None) -> Plc:
    """The PLC with Z at ``holding:100:<kind>``; ``safety.on_offset_out_of_clamp: policy`` if given."""
    output = ENCODINGS[kind][0] | {"address": f"holding:100:{kind}"}
    config: Config = plc_config(directory, **output)
    if policy is not None:
        path = directory / "compd.yaml"
        doc = yaml.safe_load(path.read_text())
        doc["safety"]["on_offset_out_of_clamp"] = policy
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        config = load_config(path)
    return Plc(config, offset=f"holding:100:{kind}")


def um(plc: Plc, raw: float) -> float:
    return raw / plc.config.doc.outputs["Z"].encoding.scale


def written_um(plc: Plc) -> list[float]:
    """Every offset compd wrote, in um."""
    return [um(plc, raw) for raw, ours in plc.offsets() if ours]


def steps_from_valid_um(plc: Plc) -> list[float]:
    """Each write's change from what the register held, where that was a value within the clamp."""
    steps, held = [], 0.0
    for raw, ours in plc.offsets():
        if ours and abs(um(plc, held)) <= MAX_UM:
            steps.append(abs(um(plc, raw) - um(plc, held)))
        held = raw
    return steps


def faulted(record: TickRecord) -> bool:
    return record.status & 0b11 == Level.FAULTED and bool(record.status & MISMATCH_BIT)


def start_holding(plc: Plc, raw: float, seconds: float = 8.0) -> tuple[Any, list[TickRecord]]:
    async def before() -> None:
        await plc.program_raw(raw)

    return run_against(plc, seconds, before_tick={0: before})


@pytest.mark.parametrize(("kind", "raw"), CASES, ids=[f"{k}-{r:g}" for k, r in CASES])
def test_a_start_on_an_out_of_clamp_register_writes_the_last_valid_offset(tmp_path, kind, raw):
    """PLC at 500/-3000 um, 1e30, 3e38, NaN or inf at start: compd writes 0 (the last valid), flags it, slews on."""
    plc = clamp_plc(tmp_path, kind)
    service, records = start_holding(plc, raw)
    written = written_um(plc)
    assert written[0] == 0.0  # not one slew step from the held value: the last valid one
    assert all(abs(w) <= MAX_UM for w in written)
    assert max(steps_from_valid_um(plc)) <= STEP_COUNTS / 10 + 1e-6
    assert faulted(records[0]) and not any(faulted(r) for r in records[1:])
    assert service.status()["counters"]["offsets_out_of_clamp"] == 1
    assert records[-1].written


def test_an_out_of_clamp_value_mid_run_is_replaced_by_the_last_offset_written(tmp_path):
    """A PLC program writing -3000 um (int32) mid-run: the next write is what compd wrote last, not -2999 um."""
    plc = clamp_plc(tmp_path, "int32")

    async def bogus() -> None:
        await plc.program(-3000.0)

    _, records = run_against(plc, 30.0, held_um=40.0, before_tick={10: bogus})
    offsets = plc.offsets()
    at = offsets.index((-30000.0, False))
    before, after = offsets[at - 1], offsets[at + 1]
    assert after == (before[0], True)
    assert all(abs(w) <= MAX_UM for w in written_um(plc))
    assert max(steps_from_valid_um(plc)) <= STEP_COUNTS / 10
    assert [faulted(r) for r in records].count(True) == 1 and faulted(records[10])


def test_the_edge_policy_ramps_from_the_nearest_clamp_edge(tmp_path):
    """With edge, a float32 register at 3e38 gets 150 um, then the offset slews down one step a tick."""
    plc = clamp_plc(tmp_path, "float32", policy="edge")
    start_holding(plc, 3e38, seconds=6.0)
    assert written_um(plc)[:5] == [150.0, 149.0, 148.0, 147.0, 146.0]


def test_the_refuse_policy_writes_no_offset_until_the_plc_holds_one_within_the_clamp(tmp_path):
    """With refuse, an int32 register at 500 um is left alone, flagged each tick; 12 um set by the PLC is followed."""
    plc = clamp_plc(tmp_path, "int32", policy="refuse")

    async def fixed_by_the_plc() -> None:
        await plc.program(12.0)

    service, records = run_against(plc, 12.0, held_um=500.0, before_tick={6: fixed_by_the_plc})
    assert all(faulted(r) and not r.written for r in records[:6])
    written = written_um(plc)
    assert abs(written[0] - 12.0) <= 1.0 and all(abs(w) <= MAX_UM for w in written)
    assert not any(faulted(r) for r in records[6:])
    assert service.status()["counters"]["offsets_out_of_clamp"] == 6
