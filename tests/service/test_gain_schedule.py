"""Gain scheduling: table lookup and ramp, config checks, the daemon following a head change bumplessly."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from compd.errors import ConfigFileError
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.files.modelwriter import model_to_yaml
from compd.model import InputSpec, Model, Output, SubModel, compile_model
from compd.model.run import TickRunner, simulate
from compd.service.config.loading import Config
from compd.service.config.modelcheck import check_model
from compd.service.loop.safety import Flag
from compd.service.loop.schedule import GainRow, GainScheduler, GainTable, first_overlap
from tests.model.conftest import first_order

from .daemon_setup import run, simulated_doc, write_config

RAMP_S = 60.0
ROWS = [
    {"when": 1, "gains": {"g1": 1.0, "g2": 1.0}},
    {"when": 2, "gains": {"g1": 0.5, "g2": 1.6}},
]
DEFAULT = {"g1": 0.8}


def two_gain_model() -> Model:
    """``disp_y_um = g1 * slow(dT) + g2 * fast(dT)`` on the spindle's rise over the shop floor."""
    subs = tuple(
        SubModel(
            name,
            name,
            InputSpec("T_spindle_degC", minus="T_shopfloor_degC"),
            first_order(gain_um_per_k, pole),
            gain_name=gain,
        )
        for name, gain, gain_um_per_k, pole in (
            ("slow", "g1", 1.2, 0.998),
            ("fast", "g2", -0.6, 0.98),
        )
    )
    return Model("two-gains", 1.0, (Output("disp_y_um", subs),))


def table(**changes: object) -> GainTable:
    """Heads 1 and 2, a default setting g1 only, a 10 s ramp; ``changes`` replace fields."""
    rows = (GainRow({"g1": 1.0, "g2": 1.0}, value=1), GainRow({"g1": 0.5, "g2": 1.6}, value=2))
    return dataclasses.replace(GainTable("spindle_head", rows, DEFAULT, 10.0), **changes)


def runner() -> TickRunner:
    compiled = compile_model(two_gain_model())
    return TickRunner(compiled, compiled.rest_state({"T_spindle_degC": 20, "T_shopfloor_degC": 20}))


# --- the table and the ramp (pure) -------------------------------------------------


def test_lookup_matches_whole_numbers_and_half_open_ranges() -> None:
    """A whole-number row matches its value (to 1e-6); a range row matches min <= key < max; else no row."""
    ranges = GainTable(
        "x_mm",
        (
            GainRow({"g1": 1.0}, value=7),
            GainRow({"g1": 2.0}, low=0.0, high=250.0),
            GainRow({"g1": 3.0}, low=250.0),
        ),
    )
    assert [ranges.lookup(k) for k in (7.0, 7.0000001, 6.5, 0.0, 249.99, 250.0, 1e6, -1.0)] == [
        0,
        0,
        1,
        1,
        1,
        2,
        2,
        None,
    ]
    assert ranges.names == ("g1",)


def test_overlapping_rows_are_found() -> None:
    """Equal numbers, a number inside a range and intersecting ranges overlap; adjacent ranges do not."""
    a, b = GainRow({}, low=0.0, high=250.0), GainRow({}, low=250.0, high=500.0)
    assert first_overlap([a, b]) is None
    assert first_overlap([a, b, GainRow({}, value=3)]) == (0, 2)
    assert first_overlap([GainRow({}, value=3), GainRow({}, value=3)]) == (0, 1)
    assert first_overlap([b, GainRow({}, low=400.0, high=600.0)]) == (0, 1)


def test_first_row_applies_at_once_and_a_change_ramps_linearly() -> None:
    """The first tick's row needs no ramp; a later change moves every gain linearly over ramp_s."""
    schedule, r = GainScheduler(table()), runner()
    schedule.update(0.0, 1.0)
    schedule.apply(r)
    assert r.gains == {"g1": 1.0, "g2": 1.0} and not schedule.ramping
    seen = []
    for t in range(1, 16):
        schedule.update(float(t), 2.0)
        schedule.apply(r)
        seen.append((r.gains["g1"], r.gains["g2"]))
    # the change is seen at t = 1: w = (t - 1) / 10
    w = np.clip((np.arange(1, 16) - 1) / 10.0, 0, 1)
    assert_allclose(seen, np.column_stack([1.0 - 0.5 * w, 1.0 + 0.6 * w]))
    assert schedule.status() | {"gains": None} == {
        "signal": "spindle_head",
        "row": 1,
        "when": "spindle_head = 2",
        "gains": None,
        "ramping": False,
        "held": False,
    }


def test_a_change_mid_ramp_starts_from_the_gains_in_use() -> None:
    """Turning back half-way ramps from the half-way gains: the gains never jump."""
    schedule, r = GainScheduler(table()), runner()
    schedule.update(0.0, 1.0)
    schedule.apply(r)
    values = []
    for t, key in [(1, 2), (2, 2), (3, 2), (4, 2), (5, 2), (6, 1), (7, 1), (16, 1)]:
        schedule.update(float(t), float(key))
        schedule.apply(r)
        values.append(r.gains["g1"])
    assert_allclose(values, [1.0, 0.95, 0.9, 0.85, 0.8, 0.8, 0.82, 1.0])


def test_a_faulted_key_holds_the_row_and_no_match_falls_back() -> None:
    """Faulted: the row in force is held. No match: the default, else the model file's own gains."""
    schedule, r = GainScheduler(table(ramp_s=0.0)), runner()
    schedule.update(0.0, 2.0)
    schedule.update(1.0, 1.0, usable=False)
    schedule.apply(r)
    assert r.gains == {"g1": 0.5, "g2": 1.6} and schedule.status()["held"]
    schedule.update(2.0, math.nan)
    schedule.apply(r)
    assert r.gains == {"g1": 0.5, "g2": 1.6}
    schedule.update(3.0, 9.0)  # no row: default g1, and g2 from the model file (1.0)
    schedule.apply(r)
    assert r.gains == {"g1": 0.8, "g2": 1.0}
    assert schedule.status()["when"] == "no row matches: default"
    bare, r2 = GainScheduler(table(default=None, ramp_s=0.0)), runner()
    bare.update(0.0, 9.0)
    bare.apply(r2)
    assert r2.gains == {"g1": 1.0, "g2": 1.0}


def test_before_any_good_key_value_the_default_is_used() -> None:
    """A key faulted from the start gives the default; its first good value then ramps (offsets exist)."""
    schedule, r = GainScheduler(table()), runner()
    schedule.update(0.0, math.nan, usable=False)
    schedule.apply(r)
    assert r.gains == {"g1": 0.8, "g2": 1.0} and schedule.row is None
    schedule.update(1.0, 2.0)
    schedule.update(6.0, 2.0)
    schedule.apply(r)
    assert_allclose([r.gains["g1"], r.gains["g2"]], [0.65, 1.3])


# --- config --------------------------------------------------------------------------


@pytest.fixture
def model_path(tmp_path: Path) -> Path:
    path = tmp_path / "two-gains.yaml"
    units = {"T_spindle_degC": "degC", "T_shopfloor_degC": "degC"}
    path.write_text(model_to_yaml(two_gain_model(), signals=units))
    return path


def head_signal(**checks: float) -> dict[str, object]:
    return {
        "driver": "machine",
        "address": "spindle_head",
        "type": "int",
        "unit": "-",
        "checks": {"min": 0, "max": 10, "hold_s": 5} | checks,
    }


def schedule_config(
    folder: Path, model: Path, changes: dict[str, object] | None = None, **schedule: object
) -> Config:
    """The simulated config on ``model`` with a spindle-head signal keying ``gain_schedule``."""
    doc = simulated_doc()
    doc["signals"]["spindle_head"] = head_signal()
    del doc["signals"]["spindle_speed_rpm"]
    # The replayed shop floor is an exact 20.0 (no sensor noise): the config says so.
    doc["signals"]["T_shopfloor_degC"]["checks"]["stuck_s"] = None
    ours: dict[str, object] = {
        "model": str(model),
        "gain_schedule": {"signal": "spindle_head", "table": ROWS, "ramp_s": RAMP_S} | schedule,
    }
    return write_config(folder, ours | (changes or {}), doc=doc)


def checked(config) -> None:
    model_file = load_model(config.model_path)
    check_model(config, model_file, model_file.compile(config.doc.period_s))


@pytest.mark.parametrize(
    ("schedule", "message"),
    [
        (
            {"signal": "head"},
            r"line \d+ \(gain_schedule.signal\): signal 'head' is not defined.*Define it",
        ),
        (
            {"table": [*ROWS, {"when": 2, "gains": {"g1": 1}}]},
            r"\(gain_schedule.table\[2\].when\): row 2 overlaps row 1.*Make the rows disjoint",
        ),
        (
            {"table": [{"when": {"min": 0, "max": 5}, "gains": {"g1": 1}}, ROWS[1]]},
            r"\(gain_schedule.table\[1\].when\): row 1 overlaps row 0",
        ),
        (
            {"table": [{"when": {"min": 5, "max": 1}, "gains": {"g1": 1}}]},
            r"\(gain_schedule.table\[0\].when\): 'min' \(5.0\) must be below 'max'",
        ),
        (
            {"table": [{"when": 1.5, "gains": {"g1": 1}}]},
            r"\(gain_schedule.table\[0\].when\): 'when' must be a whole number .* or a range",
        ),
        ({"table": [{"when": 1, "gains": {}}]}, r"gain_schedule.table\[0\].gains"),
        ({"ramp_s": -1}, r"\(gain_schedule.ramp_s\).*Give a larger value"),
        ({"ramp": 30}, r"unknown key 'ramp'.*Remove the key"),
    ],
)
def test_schedule_errors_name_the_key_and_the_fix(tmp_path, model_path, schedule, message) -> None:
    """Each mistake in 'gain_schedule' is refused at load with its line, key and fix."""
    with pytest.raises(ConfigFileError, match=message):
        schedule_config(tmp_path, model_path, **schedule)


@pytest.mark.parametrize(
    ("schedule", "place"),
    [
        (
            {"table": [ROWS[0], {"when": 2, "gains": {"g3": 1.0}}]},
            r"gain_schedule.table\[1\].gains.g3",
        ),
        ({"default": {"G1": 1.0}}, r"gain_schedule.default.G1"),
    ],
)
def test_gain_names_are_checked_against_the_model(tmp_path, model_path, schedule, place) -> None:
    """A gain the model file does not name is refused with its line and the model's gain names."""
    config = schedule_config(tmp_path, model_path, **schedule)
    with pytest.raises(
        ConfigFileError, match=rf"line \d+ \({place}\): .*no gain named.*\['g1', 'g2'\]"
    ):
        checked(config)


def test_a_model_without_gain_names_is_refused_with_the_fix(tmp_path) -> None:
    """The bundled model names no gain: the error says how to name them."""
    doc = simulated_doc()
    changes = {"signals": doc["signals"] | {"spindle_head": head_signal()}}
    config = schedule_config(tmp_path, Path(doc["model"]), changes)
    with pytest.raises(ConfigFileError, match="gain_name: g1"):
        checked(config)


# --- the daemon ------------------------------------------------------------------------

CHANGE_S, FAULT_S, UNKNOWN_S, END_S = 1200, 2400, 2600, 3000


@pytest.fixture
def head_change(tmp_path, model_path):
    """A run on virtual time: head 1, head 2 at 1200 s, the head signal faulted from 2400 s, head 7 from 2600 s."""
    t = np.arange(END_S + 1, dtype=float)
    head = np.select([t < CHANGE_S, t < UNKNOWN_S], [1, 2], 7)
    spindle = 20.0 + 12.0 * (1.0 - np.exp(-t / 900.0))
    lines = ["time_s,T_spindle_degC,T_shopfloor_degC,spindle_head"]
    lines += [f"{a:g},{b:.6f},{20.0:g},{c}" for a, b, c in zip(t, spindle, head, strict=True)]
    data = tmp_path / "heads.csv"
    data.write_text("\n".join(lines) + "\n")
    fault = {"kind": "value", "address": "spindle_head", "value": 99, "start_s": FAULT_S}
    settings = {"data": str(data), "loop": False, "faults": [fault | {"duration_s": 150}]}
    changes = {"drivers": {"machine": {"settings": settings}}, "recorder": {"enabled": True}}
    config = schedule_config(tmp_path, model_path, changes, default=DEFAULT)
    service, records = run(config, float(END_S))
    return service, records


def test_offset_follows_the_new_gains_bumplessly(head_change) -> None:
    """After a head change the offset is the model with gains ramped linearly over ramp_s: no step, no slewing."""
    service, records = head_change
    compiled = service.compensator.active.compiled
    inputs = np.array([[r.values[s] for s in compiled.signals] for r in records])
    unit = simulate(compiled, inputs, compiled.steady_state(inputs[0])).contributions  # g = 1
    t = np.array([r.t_s - records[0].t_s for r in records])
    w = np.clip((t - CHANGE_S) / RAMP_S, 0.0, 1.0)
    g1 = np.where(t < CHANGE_S, 1.0, 1.0 - 0.5 * w)
    g2 = np.where(t < CHANGE_S, 1.0, 1.0 + 0.6 * w)
    g1[t >= UNKNOWN_S] = 0.8  # head 7: no row, the default g1 and the model's g2 (1), ramped
    g2[t >= UNKNOWN_S] = 1.0
    w7 = np.clip((t - UNKNOWN_S) / RAMP_S, 0.0, 1.0)
    g1 = np.where(t >= UNKNOWN_S, 0.5 + 0.3 * w7, g1)
    g2 = np.where(t >= UNKNOWN_S, 1.6 - 0.6 * w7, g2)
    expected = -(g1 * unit[:, 0] + g2 * unit[:, 1])
    offsets = np.array([r.offsets_um["Y"] for r in records])
    assert_allclose(offsets, expected, atol=1e-9)
    assert_allclose([r.gains["g1"] for r in records], g1, atol=1e-12)
    # a step of the full gain change would have been ~3 um at once; the ramp keeps each tick small
    step_um = abs(expected[CHANGE_S + int(RAMP_S)] - expected[CHANGE_S - 1])
    assert step_um > 2.0
    assert np.max(np.abs(np.diff(offsets[CHANGE_S - 1 : CHANGE_S + 70]))) < 1.2 * step_um / RAMP_S
    assert not any(r.status & Flag.SLEWING for r in records), "the ramp, not the slew limit"


def test_status_and_recorder_show_the_gains(head_change) -> None:
    """The status snapshot names the row in force and its gains; the recordings carry one column per gain."""
    service, records = head_change
    status = service.status()["gain_schedule"]
    assert status["when"] == "no row matches: default" and status["row"] is None
    assert_allclose([status["gains"]["g1"], status["gains"]["g2"]], [0.8, 1.0])
    files = sorted((service.config.recorder_dir or Path()).glob("compd-*.csv"))
    data = load_data(files[0])
    assert_allclose(data.column("gain.g2")[: len(records)][-1], 1.0)
    assert_allclose(data.column("gain.g1")[CHANGE_S + 100], 0.5)
