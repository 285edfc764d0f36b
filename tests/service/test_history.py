"""The status page's memory: an hour of ticks in a ring, thinned on request, and the last faults, newest first."""

from __future__ import annotations

import math

from compd.service.http.history import TickHistory
from compd.service.loop.compensator import TickRecord
from compd.service.loop.signals import Health


def record(k: int, *, offset_um: float | None = None) -> TickRecord:
    """Tick ``k`` at 1 Hz: Z at ``k / 10`` um (or ``offset_um``), one temperature, status word ``k % 4``."""
    return TickRecord(
        t_s=float(k),
        wall_unix_s=1.7e9 + k,
        values={"T_degC": 20.0 + k / 100},
        health={"T_degC": Health.OK},
        reasons={},
        model_outputs={},
        contributions={},
        targets_um={},
        offsets_um={"Z": k / 10 if offset_um is None else offset_um},
        status=k % 4,
        heartbeat=k,
        written=True,
    )


def test_ring_keeps_the_last_capacity_rows_oldest_first() -> None:
    """After more ticks than it holds, the ring answers the newest ``capacity`` rows, in order."""
    history = TickHistory(["Z"], ["T_degC"], 1.0, capacity=100)
    for k in range(250):
        history.append(record(k))
    snap = history.snapshot(points=1000)
    assert snap["t_unix_s"] == [1.7e9 + k for k in range(150, 250)]
    assert snap["offsets_um"]["Z"] == [k / 10 for k in range(150, 250)]
    assert snap["status_word"] == [k % 4 for k in range(150, 250)]
    assert snap["every_ticks"] == 1


def test_thinned_snapshot_keeps_the_newest_row() -> None:
    """Asked for fewer points, every n-th row is kept counting back from the newest."""
    history = TickHistory(["Z"], ["T_degC"], 1.0, capacity=100)
    for k in range(100):
        history.append(record(k))
    snap = history.snapshot(points=10)
    assert snap["t_unix_s"] == [1.7e9 + k for k in range(9, 100, 10)]
    assert snap["every_ticks"] == 10


def test_a_fast_loop_keeps_one_row_a_second() -> None:
    """At a 0.1 s period every 10th tick is kept, so the ring still spans its hour."""
    history = TickHistory(["Z"], ["T_degC"], 0.1)
    for k in range(95):
        history.append(record(k))
    assert history.every == 10 and len(history) == 10
    assert history.snapshot()["t_unix_s"][:2] == [1.7e9, 1.7e9 + 10]


def test_unknown_values_are_null_not_nan() -> None:
    """A NaN offset (nothing known yet) is JSON's null."""
    history = TickHistory(["Z"], ["T_degC"], 1.0)
    history.append(record(0, offset_um=math.nan))
    assert history.snapshot()["offsets_um"]["Z"] == [None]
    assert TickHistory(["Z"], [], 1.0).snapshot()["t_unix_s"] == []
