"""The compd command: model check, simulate, compare and demo, end to end on real files."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from compd.cli import main
from tests.installed import console_script

CONFIG = Path(__file__).parent.parent / "config"
DATA = CONFIG / "example_spectrum.csv"
SEED000 = CONFIG / "seed000_hmc_tf.yaml"
REGRESSION = CONFIG / "seed000_linear_regression.yaml"
GATED = CONFIG / "example_gated_arx.yaml"


def run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def compare_json(capsys: pytest.CaptureFixture[str], *argv: object) -> dict:
    code, out, err = run(capsys, "compare", *argv, "--json")
    assert code == 0, err
    return json.loads(out)


def test_compare_json_has_the_contract_keys(capsys: pytest.CaptureFixture[str]) -> None:
    """compare --json prints one object whose per-output keys scripts rely on."""
    report = compare_json(capsys, SEED000, DATA)
    z = report["outputs"]["disp_z_um"]
    for key in ("fit_percent", "rms_um", "peak_to_peak_um", "max_abs_um", "uncompensated_rms_um"):
        assert isinstance(z[key], float), key
    assert report["samples"] == 2880 and report["sample_time_s"] == 10.0


def test_tf_model_beats_the_controllers_linear_regression(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Horejs 2010's claim on the example data: its TF model leaves far less residue than the built-in regression."""
    tf = compare_json(capsys, SEED000, DATA)["outputs"]["disp_z_um"]
    regression = compare_json(capsys, REGRESSION, DATA)["outputs"]["disp_z_um"]
    assert tf["fit_percent"] > 85.0
    assert tf["rms_um"] < 0.5 * regression["rms_um"]
    assert tf["rms_reduction_percent"] > 85.0


def test_compare_table_is_human_readable(capsys: pytest.CaptureFixture[str]) -> None:
    """The default output is a table naming the output, fit % and the residue figures."""
    code, out, err = run(capsys, "compare", GATED, DATA)
    assert code == 0, err
    assert "disp_y_um" in out and "fit %" in out and "residue RMS" in out
    assert "converted exactly" in err  # the 1 s model runs on 10 s data


def test_compare_with_a_renamed_measured_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--output COLUMN pairs a single-output model with a column of another name."""
    frame = pd.read_csv(DATA).rename(columns={"disp_z_um": "z_probe"})
    frame.to_csv(tmp_path / "renamed.csv", index=False)
    renamed = compare_json(capsys, SEED000, tmp_path / "renamed.csv", "--output", "z_probe")
    original = compare_json(capsys, SEED000, DATA)
    assert renamed["outputs"]["disp_z_um"]["rms_um"] == pytest.approx(
        original["outputs"]["disp_z_um"]["rms_um"]
    )


def test_simulate_writes_outputs_and_contributions(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """simulate's CSV has time, the output and each sub-model's contribution, which sum to the output."""
    out = tmp_path / "pred.csv"
    code, stdout, err = run(capsys, "simulate", SEED000, DATA, "--out", out)
    assert code == 0, err
    frame = pd.read_csv(out)
    assert list(frame.columns) == ["time_s", "disp_z_um", "disp_z_um.z_heat", "disp_z_um.etve"]
    assert len(frame) == 2880
    assert_allclose(
        frame["disp_z_um"], frame["disp_z_um.z_heat"] + frame["disp_z_um.etve"], atol=2e-6
    )
    assert "wrote 2880 samples" in stdout


def test_fit_percent_agrees_with_simulated_csv(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """fit % in compare equals Horejs 2015 eq. 2 computed from simulate's output and the measured column."""
    out = tmp_path / "pred.csv"
    assert run(capsys, "simulate", GATED, DATA, "--out", out)[0] == 0
    predicted = pd.read_csv(out)["disp_y_um"].to_numpy()
    measured = pd.read_csv(DATA)["disp_y_um"].to_numpy()
    expected = (
        1 - np.linalg.norm(measured - predicted) / np.linalg.norm(measured - measured.mean())
    ) * 100
    report = compare_json(capsys, GATED, DATA)["outputs"]["disp_y_um"]
    assert report["fit_percent"] == pytest.approx(expected, abs=1e-3)
    assert report["max_abs_um"] == pytest.approx(np.max(np.abs(measured - predicted)), abs=1e-5)


def test_model_check_lists_sub_models_with_poles_and_gates(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """model check prints each sub-model's time constants, static gain and gate."""
    code, out, err = run(capsys, "model", "check", GATED)
    assert code == 0, err
    assert "disp_y_um/heating_difference" in out
    assert "spindle_speed_rpm > 0" in out
    assert "10800.0" in out  # the ambient TF's 3 h time constant
    assert "ok" in out


def test_bad_model_exits_2_naming_file_and_place(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A malformed model ends with status 2 and the file/place message, no traceback."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        GATED.read_text().replace(
            "power_order: ascending, nk: 1,\n             num: [0.000138882459046]",
            "power_order: sideways, nk: 1,\n             num: [0.000138882459046]",
        )
    )
    code, _, err = run(capsys, "model", "check", bad)
    assert code == 2
    assert str(bad) in err and "outputs.disp_y_um.submodels[0].tf.power_order" in err
    assert "Traceback" not in err


def test_missing_signal_column_exits_2_naming_the_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Data without a column the model reads is refused naming the column and the model."""
    pd.read_csv(DATA).drop(columns=["T_shopfloor_degC"]).to_csv(tmp_path / "d.csv", index=False)
    code, _, err = run(capsys, "compare", SEED000, tmp_path / "d.csv")
    assert code == 2
    assert "T_shopfloor_degC" in err and "seed000-hmc-z" in err


def test_no_measured_column_says_how_to_choose_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Data without the model's output column points the user to --output."""
    pd.read_csv(DATA).drop(columns=["disp_z_um"]).to_csv(tmp_path / "d.csv", index=False)
    code, _, err = run(capsys, "compare", SEED000, tmp_path / "d.csv")
    assert code == 2 and "--output COLUMN" in err


def test_demo_runs_on_the_bundled_files(capsys: pytest.CaptureFixture[str]) -> None:
    """compd demo compares the three bundled models and states the TF-vs-regression result."""
    code, out, err = run(capsys, "demo")
    assert code == 0, err
    assert "seed000-hmc-z" in out and "example-gated-arx-y" in out
    assert "controller's linear regression leaves" in out


@pytest.mark.skipif(console_script("compd") is None, reason="compd is not installed as a command")
def test_installed_console_script_runs() -> None:
    """This environment's `compd` console script (beside its python, PATH or not) answers --version."""
    script = str(console_script("compd"))
    result = subprocess.run([script, "--version"], capture_output=True, text=True, check=True)
    assert result.stdout.startswith("compd ")


def test_module_entry_point_runs() -> None:
    """python -m compd.cli works without the console script (e.g. under systemd later)."""
    result = subprocess.run(
        [sys.executable, "-m", "compd.cli", "--version"], capture_output=True, text=True
    )
    assert result.returncode == 0 and "compd" in result.stdout


# compare: where the model fails (failing windows)


@pytest.fixture(scope="module")
def residue_case(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A spindle-only model on a record with rough cutting (4.5 kW, beyond calibration) from 8 h to 10 h."""
    from tests.residue_case import write_case

    return write_case(tmp_path_factory.mktemp("residue_case"))


def test_compare_json_lists_failing_windows_while_the_missing_effect_acts(
    residue_case: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """Windows fail only during and just after rough cutting, naming spindle power as outside calibration."""
    report = compare_json(capsys, *residue_case)
    windows = report["failing_windows"]
    assert windows, "rough cutting must make windows fail"
    assert report["window_s"] == 900.0 and report["window_tolerance_sources"] == {
        "disp_z_um": "calibration"
    }
    assert report["outputs"]["disp_z_um"]["window_tolerance_um"] == pytest.approx(1.2)  # 2 x 0.6
    for w in windows:
        assert {"output", "start_s", "end_s", "rms_um", "outside_calibration", "conditions"} <= set(
            w
        )
        assert 8 * 3600 <= w["start_s"] < 11 * 3600 and w["end_s"] - w["start_s"] == 900.0
        assert w["rms_um"] > 1.2
        if w["conditions"]["spindle_power_kw"] > 2.0:
            assert "spindle_power_kw" in w["outside_calibration"]
    assert sum("spindle_power_kw" in w["outside_calibration"] for w in windows) >= 4


def test_compare_tolerance_and_window_options(
    residue_case: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """--tolerance-um replaces the calibration tolerance and --window-s the 15-min window."""
    report = compare_json(capsys, *residue_case, "--tolerance-um", "100")
    assert (
        report["failing_windows"] == []
        and report["window_tolerance_sources"]["disp_z_um"] == "given"
    )
    report = compare_json(capsys, *residue_case, "--window-s", "3600")
    assert all(w["end_s"] - w["start_s"] == 3600.0 for w in report["failing_windows"])
    with pytest.raises(SystemExit) as exited:  # argparse refuses it before anything is read
        run(capsys, "compare", *residue_case, "--window-s", "0")
    assert exited.value.code == 2 and "--window-s: must be a number > 0" in capsys.readouterr().err


def test_compare_table_shows_failing_windows_with_conditions(
    residue_case: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """The human output lists failing windows as h:mm spans with mean conditions and outside-calibration signals."""
    code, out, err = run(capsys, "compare", *residue_case)
    assert code == 0, err
    assert "windows of 15 min above 1.20 um RMS (2x the calibration residue RMS)" in out
    assert "mean spindle_power_kw" in out and "outside calibration" in out
    assert "│ 8:30 " in out


def test_compare_without_calibration_record_says_which_tolerance_it_used(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A model without provenance.calibration is judged against twice this record's RMS, with a note."""
    report = compare_json(capsys, SEED000, DATA)
    assert report["window_tolerance_sources"] == {"disp_z_um": "record"}
    z = report["outputs"]["disp_z_um"]
    assert z["window_tolerance_um"] == pytest.approx(2 * z["rms_um"])
    assert any("no calibration residue RMS" in note for note in report["notes"])


@pytest.mark.parametrize(
    ("column", "value", "expected"),
    [
        ("T_spindle_degC", 1e300, "line 7, column 'T_spindle_degC': '1e+300' is beyond +-1e+15"),
        ("time_s", 1e308, "line 2881, column 'time_s': 1e+308 s of data"),
    ],
    ids=["value_1e300", "time_1e308"],
)
def test_json_commands_on_values_near_the_float_range_exit_2_naming_the_cell(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], column: str, value: float, expected: str
) -> None:
    """compare and diagnose --json on a cell of 1e300 or a time of 1e308 exit 2 with the place, no traceback."""
    data = pd.read_csv(DATA)
    data.loc[5 if column != "time_s" else len(data) - 1, column] = value
    data.to_csv(tmp_path / "d.csv", index=False)
    for command in ("compare", "diagnose"):
        code, out, err = run(capsys, command, SEED000, tmp_path / "d.csv", "--json")
        assert code == 2 and out == ""
        assert expected in err and "Traceback" not in err


def test_json_output_writes_non_finite_figures_as_null() -> None:
    """Every --json object prints NaN and +-inf, at any depth, as null: strict JSON a script can parse."""
    from compd.toolkit.summary import json_text

    text = json_text(
        {"fit_percent": float("-inf"), "rms": [1.5, float("nan")], "n": {"x": 1e308 * 10}}
    )
    assert json.loads(text) == {"fit_percent": None, "rms": [1.5, None], "n": {"x": None}}


@pytest.fixture
def terminal_80(monkeypatch: pytest.MonkeyPatch) -> None:
    """compare prints to an 80-column terminal (rich's console at width 80)."""
    from rich.console import Console

    monkeypatch.setattr("compd.cli.evaluate.console", lambda: Console(width=80, highlight=False))


def test_compare_at_80_columns_keeps_the_outside_calibration_column(
    residue_case: tuple[Path, Path], capsys: pytest.CaptureFixture[str], terminal_80: None
) -> None:
    """On an 80-column terminal the failing windows keep span, RMS and outside calibration whole.

    Condition columns that do not fit are left out (all-zero ones first) and
    named under the table; no header or signal name is cut to "spind…".
    """
    code, out, err = run(capsys, "compare", *residue_case)
    assert code == 0, err
    windows = out[out.index("windows of 15 min") :]
    assert "outside calibration" in windows
    assert all(len(line) <= 80 for line in windows.splitlines())
    assert "…" not in windows
    assert "│ 8:30  │ 8:45  │ 2.96" in windows and "spindle_power_kw" in windows
    words = " ".join(windows.split())  # the caption wraps at 80 columns
    assert "left out for width: T_coolant_degC, door_open" in words and "--wide shows all" in words


def test_compare_wide_shows_every_condition_column(
    residue_case: tuple[Path, Path], capsys: pytest.CaptureFixture[str], terminal_80: None
) -> None:
    """--wide shows every condition column whole, wider than the terminal."""
    code, out, err = run(capsys, "compare", *residue_case, "--wide")
    assert code == 0, err
    for name in ("spindle_speed_rpm", "spindle_power_kw", "feed_x_mm_per_min", "door_open"):
        assert f"mean {name}" in out
    assert "outside calibration" in out and "left out for width" not in out


def test_a_window_of_zero_length_at_the_end_is_not_judged(
    residue_case: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A record ending on a lone sample at exactly 12:00 has 48 windows of 15 min, not 49 with [12:00, 12:00]."""
    model, data = residue_case
    frame = pd.read_csv(data)
    last = frame.iloc[[-1]].assign(time_s=12 * 3600.0)  # one sample on the 49th window's start
    whole = tmp_path / "whole_hours.csv"
    pd.concat([frame, last]).to_csv(whole, index=False)
    report = compare_json(capsys, model, whole, "--tolerance-um", "0.01")
    windows = report["failing_windows"]
    assert len(windows) == 48
    assert all(w["end_s"] > w["start_s"] for w in windows)
    code, out, err = run(capsys, "compare", model, whole, "--tolerance-um", "0.01")
    assert code == 0, err
    assert "48 of 48 windows" in out


def test_model_probe_accept_shift_asks_the_daemon_to_take_the_shift() -> None:
    """--accept-shift goes in the socket request; --reset refuses it (a reset takes no probe)."""
    import argparse

    from compd.cli.modelprobe import probe_message
    from compd.errors import CompdError

    def args(**given: object) -> argparse.Namespace:
        base = {"axis": "Z", "measured_um": 42.0, "at": None, "measures": None, "reset": False}
        return argparse.Namespace(**(base | {"accept_shift": False} | given))

    assert probe_message(args(accept_shift=True))["accept_shift"] is True
    assert "accept_shift" not in probe_message(args())
    with pytest.raises(CompdError, match="--reset takes no axis, value or --accept-shift"):
        probe_message(args(axis=None, measured_um=None, reset=True, accept_shift=True))
