"""``compd extend``: a new sub-model from an effect's signal to the residue, added by superposition."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from compd.cli import main
from compd.files.modelfile import load_model

CONFIG = Path(__file__).parent.parent / "config"
DATA = CONFIG / "example_spectrum.csv"
REGRESSION = CONFIG / "seed000_linear_regression.yaml"  # 1 s model; the data is at 10 s
GATED = CONFIG / "example_gated_arx.yaml"


def extend(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, dict | str]:
    code = main(["extend", *map(str, argv)])
    out, err = capsys.readouterr()
    if code != 0:
        return code, err
    return code, json.loads(out) if "--json" in map(str, argv) else out


@pytest.fixture(scope="module")
def extended(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("extend") / "extended.yaml"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(
            [
                "extend",
                str(REGRESSION),
                str(DATA),
                "--effect",
                "spindle_speed_rpm",
                "--out",
                str(out),
                "--json",
            ]
        )
    assert code == 0
    return out, json.loads(printed.getvalue())


def test_existing_submodels_are_kept_exactly(extended: tuple[Path, dict]) -> None:
    """The parent's sub-models reappear unchanged; one sub-model is appended for the effect."""
    path, _ = extended
    parent, child = load_model(REGRESSION).model, load_model(path).model
    (parent_out,), (child_out,) = parent.outputs, child.outputs
    assert child_out.submodels[: len(parent_out.submodels)] == parent_out.submodels
    added = child_out.submodels[-1]
    assert added.name == "spindle_speed_rpm_effect"
    # Its zero is the record's first value (the spindle stood): an absolute reference, not 'start'.
    assert added.input.signal == "spindle_speed_rpm" and added.input.reference == 0.0
    assert child.name == f"{parent.name}+spindle_speed_rpm"


def test_the_new_submodel_lives_at_the_models_sample_time(extended: tuple[Path, dict]) -> None:
    """Identified on 10 s data, the TF is converted exactly to the 1 s model: compare agrees with extend."""
    path, summary = extended
    model_file = load_model(path)
    assert model_file.model.sample_time_s == 1.0
    code = main(["compare", str(path), str(DATA), "--output", "disp_z_um", "--json"])
    assert code == 0
    assert summary["fit_percent_after"] > summary["fit_percent_before"] + 20


def test_provenance_records_parent_data_and_fits(extended: tuple[Path, dict]) -> None:
    """The file says which model it came from, on which data, and the fit before and after."""
    path, summary = extended
    (record,) = load_model(path).doc.provenance.extensions
    assert record.parent_sha256 == load_model(REGRESSION).sha256
    # recorded from the model file's folder: the bundled example data by its bundled name
    assert record.data == f"bundled:{DATA.name}" and record.effect_signal == "spindle_speed_rpm"
    assert record.submodels == ["spindle_speed_rpm_effect"]
    assert record.fit_percent_before["disp_z_um"] == pytest.approx(summary["fit_percent_before"])
    assert record.fit_percent_after["disp_z_um"] == pytest.approx(summary["fit_percent_after"])


def test_verify_reports_and_records_fit_on_other_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--verify OTHER.csv gives fit % before/after there, and the file keeps those figures."""
    other = tmp_path / "other.csv"
    frame = pd.read_csv(DATA)
    frame.iloc[: len(frame) * 3 // 4].to_csv(other, index=False)
    out = tmp_path / "new.yaml"
    code, summary = extend(
        capsys, GATED, DATA, "--effect", "T_ram_degC", "--verify", other, "--out", out, "--json"
    )
    assert code == 0 and isinstance(summary, dict)
    verify = summary["verify"]
    record = load_model(out).doc.provenance.extensions[-1]
    assert record.verify_data == other.name  # beside the model: relative to its folder
    assert record.verify_fit_percent_after["disp_y_um"] == pytest.approx(
        verify["fit_percent_after"]
    )
    assert record.verify_fit_percent_before["disp_y_um"] == pytest.approx(
        verify["fit_percent_before"]
    )


def test_extending_twice_keeps_both_records(
    extended: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A second extension chains (forced here): both records, and sub-model names stay unique."""
    first, _ = extended
    out = tmp_path / "twice.yaml"
    code, _ = extend(
        capsys, first, DATA, "--effect", "spindle_speed_rpm", "--out", out, "--json", "--force"
    )
    assert code == 0
    model_file = load_model(out)
    assert [e.effect_signal for e in model_file.doc.provenance.extensions] == [
        "spindle_speed_rpm"
    ] * 2
    names = [s.name for s in model_file.model.outputs[0].submodels]
    assert names[-2:] == ["spindle_speed_rpm_effect", "spindle_speed_rpm_effect_2"]


@pytest.mark.parametrize(
    ("effect", "message"),
    [
        ("no_such_signal", "is not a signal column"),
        ("disp_z_um", "it is the measured output"),
    ],
)
def test_bad_effect_signal_is_an_input_error(
    effect: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An effect that is not a signal of the file exits 2 naming the file and the columns to use."""
    code, err = extend(capsys, REGRESSION, DATA, "--effect", effect, "--out", tmp_path / "x.yaml")
    assert code == 2 and message in err and str(DATA) in err and "T_ram_degC" in err
    assert not (tmp_path / "x.yaml").exists()


def test_constant_effect_signal_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A signal that never changes in the record cannot explain anything: exit 2, nothing written."""
    data = tmp_path / "flat.csv"
    frame = pd.read_csv(DATA)
    frame["coolant_degC"] = 21.0
    frame.to_csv(data, index=False)
    code, err = extend(
        capsys, REGRESSION, data, "--effect", "coolant_degC", "--out", tmp_path / "x.yaml"
    )
    assert code == 2 and "constant" in err


def test_an_effect_temperature_in_kelvin_named_degc_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Kelvin in a degC column would make the new sub-model's thermal zero 273 degrees off: exit 2, the fix named."""
    data = tmp_path / "kelvin.csv"
    frame = pd.read_csv(DATA)
    frame["coolant_degC"] = frame["T_ram_degC"] + 273.15
    frame.to_csv(data, index=False)
    code, err = extend(
        capsys, REGRESSION, data, "--effect", "coolant_degC", "--out", tmp_path / "x.yaml"
    )
    assert code == 2 and "in degC by its name" in err and "Subtract 273.15" in err, err
    assert not (tmp_path / "x.yaml").exists()


def test_bad_order_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--order takes 'auto' or a whole number >= 1."""
    with pytest.raises(SystemExit) as exit_info:
        main(["extend", str(REGRESSION), str(DATA), "--effect", "spindle_speed_rpm",
              "--order", "0", "--out", str(tmp_path / "x.yaml")])  # fmt: skip
    assert exit_info.value.code == 2
    assert "--order" in capsys.readouterr().err


def test_fixed_order_is_used(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--order 2 gives a second-order sub-model."""
    out = tmp_path / "o2.yaml"
    code, summary = extend(
        capsys,
        REGRESSION,
        DATA,
        "--effect",
        "spindle_speed_rpm",
        "--order",
        "2",
        "--out",
        out,
        "--json",
    )
    assert code == 0 and isinstance(summary, dict)
    assert summary["order"] == 2
    tf = load_model(out).model.outputs[0].submodels[-1].tf
    assert np.size(tf.a) == 3
    assert_allclose(tf.a[0], 1.0)


def test_an_effect_already_in_the_model_does_not_help_and_nothing_is_written(
    extended: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Extending again with the same signal adds nothing on held-out cycles: refused, no file."""
    first, _ = extended
    out = tmp_path / "twice.yaml"
    code, err = extend(capsys, first, DATA, "--effect", "spindle_speed_rpm", "--out", out)
    assert code != 0 and not out.exists()
    assert "does not help" in str(err)
