"""Model files with Pahk 2002 slope terms: schema, writer round trip, and fit_data's refusals."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from compd.errors import DataFileError, ModelFileError
from compd.files.data import load_data
from compd.files.modelfile import parse_model
from compd.files.modelwriter import model_to_yaml
from compd.model import DiscreteTF, InputSpec, Model, Output, Position, SubModel, compile_model
from compd.toolkit.fit import FitRequest, fit_data

TF = DiscreteTF.from_coefficients([0.0012345678901234567, -3.3e-7], [1.0, -0.95], 1)


def _model() -> Model:
    """An X axis: an offset sub-model and a slope sub-model with a non-zero reference position."""
    subs = (
        SubModel("T_screw", "offset", InputSpec("T_screw_degC"), TF),
        SubModel(
            "T_screw_slope",
            "slope in um per mm",
            InputSpec("T_screw_degC"),
            TF,
            gain=0.5,
            position=Position("X_position_mm", -123.456789),
        ),
    )
    return Model("x-axis", 10.0, (Output("disp_x_um", subs),))


def test_a_model_with_positions_reads_back_identical() -> None:
    """Writing then parsing a model with a slope sub-model gives the same model and the same compiled arrays."""
    model = _model()
    text = model_to_yaml(model, signals={"T_screw_degC": "degC", "X_position_mm": "mm"})
    assert 'position: {signal: "X_position_mm", reference_mm: -123.456789}' in text
    parsed = parse_model(text)
    assert parsed.model == model
    compiled = compile_model(parsed.model)
    assert compiled.signals == ("T_screw_degC", "X_position_mm")
    np.testing.assert_array_equal(compiled.position_index, [2 + 1, 1])  # constant-1 slot, X
    np.testing.assert_array_equal(compiled.position_reference_mm, [0.0, -123.456789])


def test_a_position_defaults_to_reference_zero_and_must_be_declared() -> None:
    """``reference_mm`` defaults to 0; an undeclared position signal or an unknown key is an error naming the place."""
    text = model_to_yaml(_model(), signals={"T_screw_degC": "degC", "X_position_mm": "mm"})
    plain = text.replace(", reference_mm: -123.456789", "")
    assert parse_model(plain).model.outputs[0].submodels[1].position == Position("X_position_mm")
    undeclared = text.replace('  "X_position_mm": {unit: "mm"}\n', "")
    with pytest.raises(ModelFileError, match=r"X_position_mm.*not declared"):
        parse_model(undeclared)
    misspelt = text.replace("reference_mm:", "ref_mm:")
    with pytest.raises(ModelFileError, match="ref_mm"):
        parse_model(misspelt)


@pytest.fixture(scope="module")
def positions_csv(tmp_path_factory: pytest.TempPathFactory):
    """A small record: a temperature ramp measured at two alternating positions."""
    n = 400
    t_degc = 20.0 + np.linspace(0.0, 4.0, n) + 0.3 * np.sin(np.arange(n) / 15.0)
    x_mm = np.where((np.arange(n) // 20) % 2 == 0, 100.0, 600.0)
    path = tmp_path_factory.mktemp("fitpos") / "x.csv"
    pd.DataFrame(
        {
            "time_s": np.arange(n) * 10.0,
            "T_screw_degC": t_degc,
            "X_position_mm": x_mm,
            "spindle_speed_rpm": np.where(np.arange(n) % 50 < 25, 3000.0, 0.0),
            "disp_x_um": 0.0115 * x_mm * (t_degc - t_degc[0]),
        }
    ).to_csv(path, index=False)
    return path


@pytest.mark.parametrize(
    ("options", "message", "where"),
    [
        ({"position": "T_screw_degC"}, "also the output or an input", "--position"),
        ({"position": "X_position_mm", "phase_gate": "spindle_speed_rpm"}, "not supported",
         "--position"),
        ({"position": "X_position_mm", "position_reference_mm": float("nan")}, "not a finite",
         "--position-reference-mm"),
        ({"position": "Y_position_mm"}, "Y_position_mm", ""),
    ],
    ids=["position-is-an-input", "with-phase-gate", "nan-reference", "unknown-column"],
)  # fmt: skip
def test_fit_data_refuses_bad_position_arguments(
    positions_csv, options: dict, message: str, where: str
) -> None:
    """A position that is an input, combined with a phase gate, unknown, or a NaN reference is refused by name."""
    data = load_data(positions_csv)
    with pytest.raises(DataFileError, match=message) as raised:
        fit_data(
            data, FitRequest(output="disp_x_um", inputs=["T_screw_degC"], method="mlr", **options)
        )
    assert where in str(raised.value)


def test_fit_data_with_a_position_writes_offset_and_slope_submodels(positions_csv) -> None:
    """An MLR fit with a position gives an offset and a slope sub-model; the slope is alpha (0.0115 um/(mm K))."""
    data = load_data(positions_csv)
    result = fit_data(
        data,
        FitRequest(
            output="disp_x_um", inputs=["T_screw_degC"], method="mlr", position="X_position_mm"
        ),
    )
    offset, slope = result.model.outputs[0].submodels
    assert offset.position is None and slope.position == Position("X_position_mm", 0.0)
    assert slope.tf.static_gain() == pytest.approx(0.0115, rel=1e-6)
    assert abs(offset.tf.static_gain()) < 1e-6
    assert result.identification.fit_percent > 99.9
    assert parse_model(result.yaml_text).model == result.model
