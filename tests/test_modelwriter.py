"""Model files written by compd read back to the identical model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from compd.files.modelfile import parse_model
from compd.files.modelschema import CalibrationDoc, ProvenanceDoc
from compd.files.modelwriter import model_to_yaml, yaml_float
from compd.model import (
    ContinuousTF,
    DiscreteTF,
    Gate,
    GateTarget,
    InputSpec,
    Model,
    Output,
    SubModel,
    compile_model,
)
from compd.model.structure import AmbientZero


def _model() -> Model:
    """Every feature the schema has: both TF forms, minus, fixed reference, gain, all gate kinds."""
    z = (
        SubModel(
            "heat",
            'spindle "front" bearings: heating',
            InputSpec("T_spindle_degC", minus="T_ambient_degC"),
            DiscreteTF.from_coefficients(
                [1.2345678901234567e-05, -3.3e-7], [1.0, -1.9987, 0.99870123], 1
            ),
            gain=0.87,
            gate=Gate("speed_rpm", 0.0, True, GateTarget.INPUT),
        ),
        SubModel(
            "ambient",
            "ambient",
            InputSpec("T_ambient_degC", reference=20.0),
            ContinuousTF.from_coefficients([0.0162, 10.74, 5.368], [0.002098, 2.379, 1.0], 10.0),
        ),
        SubModel(
            "standstill",
            "standing spindle",
            InputSpec("T_ambient_degC"),
            DiscreteTF.from_coefficients([0.1], [1.0, -0.5], 0),
            gate=Gate("speed_rpm", 1.0, False, GateTarget.OUTPUT),
        ),
    )
    x = (
        SubModel(
            "static",
            "regression",
            InputSpec("T_spindle_degC"),
            DiscreteTF.from_coefficients([7.0], [1.0]),
        ),
    )
    return Model("round-trip: test", 1.0, (Output("disp_z_um", z), Output("disp_x_um", x)))


UNITS = {"T_spindle_degC": "degC", "T_ambient_degC": "degC", "speed_rpm": "rpm"}


def test_written_model_reads_back_identical():
    """parse_model(model_to_yaml(model)).model == model, coefficient for coefficient."""
    model = _model()
    parsed = parse_model(model_to_yaml(model, description="a: test", signals=UNITS))
    assert parsed.model == model
    assert parsed.doc.description == "a: test"
    assert {name: s.unit for name, s in (parsed.doc.signals or {}).items()} == UNITS


def test_written_model_compiles():
    """A written model passes the same checks (causal, stable) as a hand-written one."""
    parsed = parse_model(model_to_yaml(_model()))
    assert compile_model(parsed.model).n_submodels == 4


def test_provenance_reads_back_identical():
    """Provenance with calibration figures and the ranges of every column survives the round trip."""
    provenance = ProvenanceDoc(
        data="calib.csv",
        command="compd fit --data calib.csv --output disp_z_um --inputs T_spindle_degC",
        created="2026-11-23T05:00:00Z",
        compd_version="0.1.0",
        method="oe",
        fit_percent={"disp_z_um": 98.76543210987654},
        calibration=CalibrationDoc(
            data="calib.csv",
            samples=2880,
            sample_time_s=10.0,
            fit_percent={"disp_z_um": 98.76543210987654},
            rms_um={"disp_z_um": 0.123456789},
            ranges={"T_spindle_degC": (19.5, 31.25), "disp_z_um": (-1.0e-5, 42.0)},
        ),
        notes="orders: na=0 nb=[2] nf=[2] nk=[1]",
    )
    parsed = parse_model(model_to_yaml(_model(), provenance=provenance))
    assert parsed.doc.provenance == provenance


@pytest.mark.parametrize("value", [1e-05, -3.3e-07, 1e20, 0.1, 7.0, 0.0, -2.5e-300, 123456789.125])
def test_numbers_are_written_as_yaml_floats_at_full_precision(value):
    """Every float is written so PyYAML reads back the same float (1.0e-05, never the string 1e-05)."""
    text = yaml_float(value)
    read = yaml.safe_load(text)
    assert isinstance(read, float) and read == value


def test_signals_must_cover_every_signal_used():
    """Declaring units for some signals but not all is refused (the schema would reject the file)."""
    with pytest.raises(ValueError, match="speed_rpm"):
        model_to_yaml(_model(), signals={"T_spindle_degC": "degC", "T_ambient_degC": "degC"})


def test_a_thermal_zero_that_follows_the_ambient_reads_back_and_moves_the_references():
    """``ambient: {signal, reference, moves}`` reads back; a start 2 degC warmer moves the listed references by 2."""
    model = replace(_model(), ambient=AmbientZero("T_ambient_degC", 20.0, ("T_ambient_degC",)))
    back = parse_model(model_to_yaml(model, signals=UNITS)).model
    assert back == model
    values = {"T_spindle_degC": 25.0, "T_ambient_degC": 22.0, "speed_rpm": 0.0}
    compiled = compile_model(back)
    fixed = np.isfinite(compiled.fixed_reference)
    assert compiled.fixed_reference[fixed].tolist() == [20.0]
    assert compiled.rest_state(values).reference[fixed].tolist() == [22.0]
    still = compile_model(replace(model, ambient=AmbientZero("T_ambient_degC", 20.0)))
    assert still.rest_state(values).reference[fixed].tolist() == [20.0], (
        "only the listed inputs move"
    )
