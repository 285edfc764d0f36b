"""The loop's recorded row made cheaply: the same columns, values and text as the plain way."""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np

from compd.service.loop.compensator import TickRecord
from compd.service.loop.signals import Health
from compd.service.recording.csvline import LineFormats, Stamps, cell, stamp
from compd.service.recording.recorder import Recorder
from compd.service.recording.ticks import RowLayout, tick_row_of


def record(t_s: float, **changes: object) -> TickRecord:
    base: dict[str, object] = {
        "t_s": t_s,
        "wall_unix_s": 1.8e9 + t_s,
        "values": {"T_a_degC": 20.5, "speed_rpm": 0.0},
        "health": {"T_a_degC": Health.OK, "speed_rpm": Health.HELD},
        "reasons": {},
        "model_outputs": {"disp_z_um": -0.0},
        "contributions": {"disp_z_um/spindle": -0.0, "disp_z_um/ambient": 1.25},
        "targets_um": {"Z": 0.0},
        "offsets_um": {"Z": 0.0},
        "status": 5,
        "heartbeat": 7,
        "written": True,
        "acknowledged_um": {"Z": math.nan},
        "read": {"T_a_degC": 20.5, "speed_rpm": math.nan},
        "probe_adjustments_um": {"disp_z_um": 0.5},
    }
    return TickRecord(**(base | changes))  # type: ignore[arg-type]


def test_the_row_layout_gives_tick_rows_columns_and_values_in_order() -> None:
    """Columns and values are tick_row's dict, in its order, the columns one tuple while the keys stay."""
    layout = RowLayout()
    first = layout.row(record(1.0))
    second = layout.row(record(2.0, values={"T_a_degC": 21.0, "speed_rpm": 10.0}))
    for (columns, values), t_s in ((first, 1.0), (second, 2.0)):
        expected = tick_row_of(
            record(t_s) if t_s == 1.0 else record(2.0, values={"T_a_degC": 21.0, "speed_rpm": 10.0})
        )
        assert columns == tuple(expected)
        assert [repr(v) for v in values] == [repr(v) for v in expected.values()]
    assert second[0] is first[0]
    other = layout.row(record(3.0, gains={"g1": 0.8}))
    assert other[0] == tuple(tick_row_of(record(3.0, gains={"g1": 0.8})))


def test_names_that_clash_are_recorded_as_tick_row_records_them() -> None:
    """A signal named like another column (read.X) keeps tick_row's last value, not two columns."""
    clash = record(1.0, values={"read.T_a_degC": 1.0, "T_a_degC": 2.0})
    columns, values = RowLayout().row(clash)
    expected = tick_row_of(clash)
    assert columns == tuple(expected) and values == list(expected.values())


def test_a_line_of_one_format_is_the_text_of_each_cell() -> None:
    """Floats, ints, bools, NaN and negative zeros (written 0) read as cell() writes them, one by one."""
    lines = LineFormats()
    rng = random.Random(3)
    choices = [-0.0, 0.0, 1.5, -2.0, 7, True, False, math.nan, -math.inf, 1e-300, -1e-300, 10**20]
    for _ in range(5000):
        values = [rng.choice(choices) for _ in range(rng.randrange(1, 9))]
        assert lines.line("S", values) == "S," + ",".join(map(cell, values)) + "\n"
    for values in ([np.float64(-0.0), "a,b"], []):
        assert lines.line("S", values) == "S," + ",".join(map(cell, values)) + "\n"


def test_stamps_are_datetimes_text_to_the_millisecond() -> None:
    """The minute kept between rows changes nothing: every stamp is datetime.isoformat's, rounding included."""
    stamps = Stamps()
    rng = random.Random(5)
    times = [1.8e9 + k * 0.1 for k in range(2000)] + [rng.uniform(0, 4e9) for _ in range(20000)]
    times += [1.8e9 + 0.9999995, 1.8e9 + 59.9999996, 0.0, -1.5]
    for t_s in times:
        assert stamps(t_s) == stamp(t_s)


def test_rows_given_as_values_write_the_same_file_as_rows_given_as_dicts(tmp_path: Path) -> None:
    """record_values and record write the same bytes; new columns start a new file in both."""
    texts = []
    for way in ("dict", "values"):
        directory = tmp_path / way
        with Recorder(
            directory, max_file_bytes=10**6, max_file_age_s=1e9, max_total_bytes=10**7
        ) as rec:
            for k in range(5):
                row = tick_row_of(record(float(k), gains={"g": 1.0} if k >= 3 else {}))
                if way == "dict":
                    rec.record(row, at_s=1.8e9 + k)
                else:
                    rec.record_values(tuple(row), list(row.values()), at_s=1.8e9 + k)
        texts.append(
            [
                [line for line in p.read_text().splitlines() if not line.startswith("# run_id")]
                for p in sorted(directory.iterdir())
            ]
        )
    assert texts[0] == texts[1] and len(texts[0]) == 2
