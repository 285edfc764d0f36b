"""``compd fit``: writes a model file that ``compd compare`` reproduces, and refuses bad input with exit 2."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import scipy.signal

from compd.cli import main
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.toolkit.evaluate import compare, evaluate
from tests.model.thermal_cases import held_levels, thermal_second_order

TS = 10.0


@pytest.fixture(scope="module")
def calibration_csv(tmp_path_factory):
    """24 h at 10 s: spindle and ambient temperatures, spindle on/off, z displacement with 1 % noise."""
    rng = np.random.default_rng(21)
    n = int(24 * 3600 / TS)
    spindle = 22.0 + held_levels(rng, n, TS)
    ambient = 20.0 + 0.3 * held_levels(rng, n, TS, lag_s=3600.0)
    speed = np.where(np.arange(n) % 1080 < 600, 6000.0, 0.0)
    heat_b, heat_a = thermal_second_order((1200.0, 4800.0), 3.0, 0.4, TS)
    amb_b, amb_a = thermal_second_order((2400.0, 7200.0), -2.0, 0.5, TS)
    z = scipy.signal.lfilter(heat_b, heat_a, spindle - spindle[0]) + scipy.signal.lfilter(
        amb_b, amb_a, ambient - ambient[0]
    )
    z += 0.01 * np.std(z) * rng.standard_normal(n)
    path = tmp_path_factory.mktemp("fit") / "calib.csv"
    pd.DataFrame(
        {
            "time_s": np.arange(n) * TS,
            "T_spindle_degC": spindle,
            "T_ambient_degC": ambient,
            "T_const_degC": np.full(n, 20.0),
            "spindle_speed_rpm": speed,
            "disp_z_um": z,
        }
    ).to_csv(path, index=False, float_format="%.9g")
    return path


def _fit(csv, out, *extra):
    return main(
        [
            "fit",
            "--data",
            str(csv),
            "--output",
            "disp_z_um",
            "--inputs",
            "T_spindle_degC,T_ambient_degC",
            "--out",
            str(out),
            *extra,
        ]
    )


@pytest.mark.parametrize(
    "options",
    [
        ("--method", "arx"),
        ("--method", "oe", "--order", "2"),
        ("--method", "mlr"),
        ("--method", "arx", "--order", "2", "--phase-gate", "spindle_speed_rpm"),
    ],
    ids=["arx-auto", "oe-2", "mlr", "arx-gated"],
)
def test_compare_reproduces_the_fit_printed_by_fit(calibration_csv, tmp_path, capsys, options):
    """The model file's fit % (the one fit prints) is what compare computes on the same data, to 1e-6."""
    out = tmp_path / "model.yaml"
    assert _fit(calibration_csv, out, *options) == 0
    printed = capsys.readouterr().out
    assert "free-run simulation fit" in printed
    model_file = load_model(out)
    fitted = model_file.doc.provenance.fit_percent["disp_z_um"]
    assert f"{fitted:.2f} %" in printed
    (comparison,) = compare(evaluate(model_file, load_data(calibration_csv)))
    assert abs(comparison.fit_percent - fitted) < 1e-6


def test_provenance_records_the_calibration(calibration_csv, tmp_path):
    """Provenance names method, data, command, time and version, and the range of every data column."""
    out = tmp_path / "model.yaml"
    assert _fit(calibration_csv, out, "--method", "oe", "--order", "1") == 0
    provenance = load_model(out).doc.provenance
    data = load_data(calibration_csv)
    assert provenance.method == "oe"
    assert provenance.created is not None and provenance.created.endswith("Z")
    assert provenance.compd_version
    calibration = provenance.calibration
    assert calibration is not None
    assert calibration.samples == len(data) and calibration.sample_time_s == TS
    assert set(calibration.ranges) == set(data.columns)
    low, high = calibration.ranges["spindle_speed_rpm"]
    assert (low, high) == (0.0, 6000.0)
    assert calibration.rms_um["disp_z_um"] > 0.0


def test_gated_model_switches_the_heating_tf_input(calibration_csv, tmp_path):
    """--phase-gate gives each input a cooling sub-model and a heating one gated on its input by SIGNAL > 0."""
    out = tmp_path / "model.yaml"
    assert _fit(calibration_csv, out, "--method", "mlr", "--phase-gate", "spindle_speed_rpm") == 0
    submodels = load_model(out).model.outputs[0].submodels
    assert [s.name for s in submodels] == [
        "T_spindle_degC",
        "T_spindle_degC_heating",
        "T_ambient_degC",
        "T_ambient_degC_heating",
    ]
    gate = submodels[1].gate
    assert gate is not None and gate.signal == "spindle_speed_rpm" and gate.threshold == 0.0
    assert gate.above and gate.target.value == "input"
    assert submodels[0].gate is None


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (("--inputs", "T_nowhere_degC"), "no column 'T_nowhere_degC'"),
        (("--inputs", " , "), "--inputs: no inputs given"),
        (("--inputs", "T_spindle_degC,disp_z_um"), "output column 'disp_z_um' is also among"),
        (("--order", "0"), "--order: order must be"),
        (("--order", "two"), "--order: order 'two' is not a number"),
        (
            ("--inputs", "T_const_degC"),
            "column 'T_const_degC': input column 'T_const_degC' is constant",
        ),
        (
            ("--phase-gate", "T_const_degC"),
            "--phase-gate T_const_degC: the phase-gate signal is always > 0",
        ),
    ],
)
def test_bad_input_exits_2_naming_file_place_and_fix(
    calibration_csv, tmp_path, capsys, options, message
):
    """Unknown or constant columns, no inputs, the output among the inputs and bad orders end with exit 2."""
    out = tmp_path / "model.yaml"
    arguments = ["--data", str(calibration_csv), "--output", "disp_z_um", "--out", str(out)]
    if "--inputs" not in options:
        arguments += ["--inputs", "T_spindle_degC"]
    assert main(["fit", *arguments, *options]) == 2
    error = capsys.readouterr().err
    assert str(calibration_csv) in error
    assert message in error
    assert not out.exists()


def test_the_expected_fit_on_new_data_is_printed_first_and_stored(
    calibration_csv, tmp_path, capsys
):
    """fit leads with the median of the held-out folds (pooled figure beside it); model check too."""
    model = tmp_path / "auto.yaml"
    assert _fit(calibration_csv, model) == 0
    printed = " ".join(capsys.readouterr().out.split())  # as read, whatever the wrapping
    held_out = load_model(model).doc.provenance.cross_validation
    assert held_out is not None
    expected = held_out.fold_median_percent[held_out.kept]
    pooled = held_out.nested_fit_percent[held_out.kept]
    assert (
        set(held_out.nested_fit_percent)
        == set(held_out.fold_spread_percent)
        == set(held_out.fold_median_percent)
        == {"lagbank", "mlr"}
    )
    assert held_out.expected_percent() == pytest.approx(expected)
    n_folds = int(held_out.folds.split()[3])  # "leave one of N ... out"
    assert (
        f"expected fit on new data {expected:.1f} % (nested cross-validation: the median of its "
        f"{n_folds} held-out folds, pooled {pooled:.1f} %)"
    ) in printed
    assert main(["model", "check", str(model)]) == 0
    checked = capsys.readouterr().out.splitlines()
    assert checked[1].startswith(f"expected fit on new data: {expected:.1f} %")


def test_a_model_file_without_the_nested_figure_still_loads_and_says_its_figure_is_optimistic(
    calibration_csv, tmp_path, capsys
):
    """A file written before the nested figure existed loads; model check labels its figure as optimistic."""
    model = tmp_path / "auto.yaml"
    assert _fit(calibration_csv, model) == 0
    capsys.readouterr()
    text = model.read_text()
    start = text.index("    nested_fit_percent:")
    end = text.index("    calibration_fit_percent:")
    text = text[:start] + text[end:]
    # ... and before the headline was written: it is derived from the cross-validation
    text = text[: text.index("  headline:\n")] + text[text.index("  data:") :]
    old = tmp_path / "old.yaml"
    old.write_text(text)
    held_out = load_model(old).doc.provenance.cross_validation
    assert held_out is not None and held_out.nested_fit_percent == {}
    assert held_out.expected_percent() == held_out.fit_percent[held_out.kept]
    assert main(["model", "check", str(old)]) == 0
    checked = " ".join(capsys.readouterr().out.split())
    assert "settings chosen on the same folds (optimistic)" in checked


def test_fitted_model_carries_the_calibrations_first_values_as_its_thermal_zero(
    calibration_csv, tmp_path
):
    """fit writes the calibration's first values as references (not 'start'); a warm start counts drift from them."""
    out = tmp_path / "model.yaml"
    assert _fit(calibration_csv, out, "--method", "oe", "--order", "1") == 0
    model_file = load_model(out)
    data = load_data(calibration_csv)
    subs = model_file.model.outputs[0].submodels
    for sub in subs:
        assert sub.input.reference == pytest.approx(data.column(sub.input.signal)[0], abs=1e-6)
    assert "thermal zero" in model_file.doc.provenance.notes
    ambient = model_file.model.ambient  # a cold machine is in equilibrium with today's air
    assert ambient is not None and ambient.signal == "T_ambient_degC"
    assert ambient.reference == pytest.approx(data.column("T_ambient_degC")[0], abs=1e-6)
    compiled = model_file.compile()
    warm = {"T_spindle_degC": data.column("T_spindle_degC")[0] + 5.0,
            "T_ambient_degC": data.column("T_ambient_degC")[0] + 1.0}  # fmt: skip
    steady = compiled.steady_state(warm)
    static_gain = compiled.b.sum(axis=1) / compiled.a.sum(axis=1)
    # The shop is 1 degC warmer: the zero moves with it, so the spindle is 4 degC above it.
    rises = np.array([4.0 if s.input.signal == "T_spindle_degC" else 0.0 for s in subs])
    y = np.asarray(compiled.b[:, 0] * rises + steady.z[:, 0])  # the DF2T output at the next tick
    assert y.sum() == pytest.approx(float(static_gain @ rises), rel=1e-9)
    assert abs(y.sum()) > 1.0, "a warm machine's drift from the thermal zero is compensated"


def test_fit_from_inside_the_records_last_cycle_is_judged_on_folds_of_that_part(
    calibration_csv, tmp_path, capsys
):
    """``--from 22:00`` of a 24 h record of 3 h cycles: the last 2 h are cut into their own folds.

    The whole record's cycles leave those hours in one fold, with nothing to
    hold out against (it used to end in "no held-out predictions to score").
    """
    assert _fit(calibration_csv, tmp_path / "m.yaml", "--from", "22:00") == 0
    out = capsys.readouterr().out
    assert "of the scored part" in out and "expected fit on new data" in out


def test_an_oe_model_that_cannot_run_is_refused_as_a_fit_with_the_default_named(tmp_path, capsys):
    """Random machine 4 (14 sensors, one record): OE at order 1 finds a pole so near 1 that a gain is 2e7 um/K.

    The refusal names the data file and the option, and points to the default
    fit, instead of a model-file message about units and coefficients.
    """
    from compd.sim.machines import random_machine, write_case

    case = random_machine(4)
    write_case(case, tmp_path)
    code = main(
        [
            "fit",
            "--data",
            str(tmp_path / "calibration"),
            "--output",
            case.output,
            "--inputs",
            ",".join(case.inputs),
            "--method",
            "oe",
            "--order",
            "1",
            "--out",
            str(tmp_path / "m.yaml"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "calibration/01.csv" in err and "--method oe" in err and "cannot run" in err
    assert "the default (no --method)" in err
    assert not (tmp_path / "m.yaml").exists()


def test_oe_whose_every_start_is_unstable_points_to_the_default_not_a_longer_record(
    tmp_path, capsys
):
    """Random machine 2 (a 37 h record, 11 sensors): the ARX start of every OE order has a pole outside the unit circle.

    More data would not help: the refusal says which start failed and that
    the default fit needs no poles of its own.
    """
    from compd.sim.machines import random_machine, write_case

    case = random_machine(2)
    write_case(case, tmp_path)
    argv = ["fit", "--data", str(tmp_path / "calibration"), "--output", case.output]
    argv += ["--inputs", ",".join(case.inputs), "--method", "oe", "--out", str(tmp_path / "m.yaml")]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert "no output-error model of order 1..3" in err and "at order 1" in err
    assert "unstable" in err and "Fit without --method" in err
    assert "longer record" not in err
    assert not (tmp_path / "m.yaml").exists()


def test_fit_ends_with_what_the_other_signals_cannot_verify(calibration_csv, tmp_path, capsys):
    """After the fit summary: per input, the error a wrong reading causes unseen, its remedy, the defaults said."""
    model = tmp_path / "verify.yaml"
    assert _fit(calibration_csv, model, "--method", "arx", "--order", "2") == 0
    out = capsys.readouterr().out
    assert out.index("what the sensors can verify") > out.index(f"wrote {model}")
    rows = [line for line in out.splitlines() if line.startswith("│ T_")]
    assert {row.split()[1] for row in rows} == {"T_spindle_degC", "T_ambient_degC"}
    assert any("not verifiable: add a redundant sensor beside" in row for row in rows)
    assert "a fit has no service config: the default plausibility settings" in " ".join(out.split())


@pytest.mark.parametrize(
    ("change", "output", "inputs", "message", "fix"),
    [
        (
            lambda d: d.assign(T_spindle_degC=d.T_spindle_degC + 273.15),
            "disp_z_um",
            "T_spindle_degC",
            "input column 'T_spindle_degC' is in degC by its name, but its median is",
            "Subtract 273.15 (it reads kelvin), or name it T_spindle_K",
        ),
        (
            lambda d: d.rename(columns={"T_spindle_degC": "T_spindle_K"}),
            "disp_z_um",
            "T_spindle_K",
            "input column 'T_spindle_K' is in K by its name",
            "Add 273.15 (it reads degC)",
        ),
        (
            lambda d: d.assign(disp_z_mm=d.disp_z_um / 1000.0),
            "disp_z_mm",
            "T_spindle_degC",
            "the output column 'disp_z_mm' is in mm by its name; compd's outputs",
            "Convert it to um in a column named ..._um",
        ),
        (
            lambda d: d.assign(disp_z_um=0.0),
            "disp_z_um",
            "T_spindle_degC",
            "the output column 'disp_z_um' is constant (0) over the whole record",
            "Name the measured displacement column with --output",
        ),
    ],
    ids=["kelvin-named-degC", "degC-named-K", "output-in-mm", "constant-output"],
)
def test_a_column_whose_values_contradict_its_name_is_refused(
    calibration_csv, tmp_path, capsys, change, output, inputs, message, fix
):
    """Kelvin in a degC column (or the reverse), an output in mm and a constant output exit 2, not a wrong model."""
    data = tmp_path / "changed.csv"
    change(pd.read_csv(calibration_csv)).to_csv(data, index=False)
    out = tmp_path / "model.yaml"
    arguments = ["--data", str(data), "--output", output, "--inputs", inputs, "--out", str(out)]
    assert main(["fit", *arguments]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert str(data) in error and message in error and fix in error, error
    assert not out.exists()


def recorded(frame: pd.DataFrame, path, units: dict[str, str]) -> None:
    """``frame`` as compd's recorder writes a CSV: each column's unit in a ``# unit.NAME: UNIT`` line."""
    with open(path, "w") as handle:
        handle.writelines(f"# unit.{name}: {unit}\n" for name, unit in units.items())
        frame.to_csv(handle, index=False)


def test_a_recorded_files_units_are_the_models(calibration_csv, tmp_path, capsys):
    """A column named without a unit keeps the unit compd's recorder wrote for it (degC, not '-', which a
    config's degC signal could not feed); a recorded unit its values contradict is refused."""
    frame = pd.read_csv(calibration_csv).rename(columns={"T_spindle_degC": "spindle_temp"})
    data = tmp_path / "recorded.csv"
    recorded(frame, data, {"spindle_temp": "degC"})
    out = tmp_path / "model.yaml"
    argv = ["fit", "--data", str(data), "--output", "disp_z_um", "--out", str(out)]
    assert main([*argv, "--inputs", "spindle_temp,T_ambient_degC"]) == 0
    assert load_model(out).signal_units()["spindle_temp"] == "degC"
    recorded(frame, data, {"spindle_temp": "K"})
    assert main([*argv, "--inputs", "spindle_temp"]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert "input column 'spindle_temp' is in K as the file records it" in error
    assert "Add 273.15 (it reads degC), or record it with the config's 'unit: degC'" in error
    recorded(frame, data, {"disp_z_um": "mm"})
    assert main([*argv, "--inputs", "spindle_temp"]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert "the output column 'disp_z_um' is in mm as the file records it" in error


def test_compare_refuses_a_record_in_another_unit_than_the_model_reads(
    calibration_csv, tmp_path, capsys
):
    """A recording that says an input is in degF, for a model fitted in degC, exits 2; another spelling of degC runs."""
    model = tmp_path / "model.yaml"
    assert _fit(calibration_csv, model) == 0
    frame = pd.read_csv(calibration_csv)
    data = tmp_path / "recorded.csv"
    recorded(frame, data, {"T_spindle_degC": "degF"})
    capsys.readouterr()
    assert main(["compare", str(model), str(data)]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert "column 'T_spindle_degC' is recorded in 'degF', and model" in error
    assert "reads it in 'degC'" in error and "Convert the column to 'degC'" in error
    recorded(frame, data, {"T_spindle_degC": "°C"})
    assert main(["compare", str(model), str(data)]) == 0


def test_a_time_column_in_milliseconds_is_refused_naming_the_data(
    calibration_csv, tmp_path, capsys
):
    """``time_s`` holding ms makes a 10 s record step 10,000 s: fit and compare name the data file
    and the fix (divide by 1000), not the model's sample time."""
    frame = pd.read_csv(calibration_csv)
    frame["time_s"] *= 1000.0
    data = tmp_path / "in-ms.csv"
    frame.to_csv(data, index=False)
    out = tmp_path / "model.yaml"
    fit = ["fit", "--output", "disp_z_um", "--inputs", "T_spindle_degC", "--out", str(out)]
    assert main([*fit, "--data", str(data)]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert f"{data}: the time column: steps" in error and "divide it by 1000" in error, error
    assert not out.exists()
    assert main([*fit, "--data", str(calibration_csv)]) == 0
    capsys.readouterr()
    assert main(["compare", str(out), str(data)]) == 2
    error = " ".join(capsys.readouterr().err.split())
    assert f"{data}: the time column: steps" in error and "divide it by 1000" in error, error
