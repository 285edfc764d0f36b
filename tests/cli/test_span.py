"""``--from``/``--until`` on one continuous record, and ``--inputs``/``--candidates`` globs and ``all``.

The record is known exactly: two temperatures that start far from zero drive
first-order lags (2 h and 1 h) from rest, so the model must be run from the
file's start, with the file's first values as references, to reproduce the
displacement at any later time.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.signal

from compd.cli import main
from compd.files.data import load_data
from compd.files.modelfile import load_model
from compd.model.metrics import Comparison
from compd.toolkit.evaluate import evaluate
from tests.clirun import compd

TS = 60.0
HOURS = 48
CUT_S = 32 * 3600.0  # the cut of the issue: fit on the first 32 h, judge on the rest
OUTPUT = "disp_ch3_um"


def _lag(u: np.ndarray, tau_s: float, gain: float) -> np.ndarray:
    """First-order ZOH lag from rest: ``gain (1 - p) / (1 - p q^-1)`` delayed one sample."""
    pole = np.exp(-TS / tau_s)
    return scipy.signal.lfilter([0.0, gain * (1.0 - pole)], [1.0, -pole], u)


def _record(seed: int = 7, *, after_cut: float = 0.0) -> pd.DataFrame:
    """48 h at 60 s: spindle heat cycles and ambient; ``after_cut`` shifts T1 after 32 h."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(int(HOURS * 3600 / TS)) * TS
    heating = (time_s % (8 * 3600.0)) < 4 * 3600.0
    t1 = 25.0 + _lag(5.0 * heating, 1800.0, 1.0) + 0.02 * rng.standard_normal(time_s.size)
    t1 = t1 + after_cut * (time_s >= CUT_S)
    t2 = 21.0 + 1.5 * np.sin(2 * np.pi * time_s / (11 * 3600.0))
    disp = _lag(t1 - t1[0], 7200.0, 3.0) + _lag(t2 - t2[0], 3600.0, -1.0)
    disp += 0.01 * rng.standard_normal(time_s.size)
    return pd.DataFrame(
        {
            "time_s": time_s,
            "T1": t1,
            "T2": t2,
            "spindle_speed_rpm": 3000.0 * heating,
            "disp_ch1_um": 0.5 * disp,
            OUTPUT: disp,
        }
    )


def _write(frame: pd.DataFrame, path: Path) -> Path:
    frame.to_csv(path, index=False, float_format="%.9g")
    return path


@pytest.fixture(scope="module")
def record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write(_record(), tmp_path_factory.mktemp("span") / "log.csv")


@pytest.fixture(scope="module")
def model(record: Path) -> Path:
    """An order-1 OE model of the whole record: close to the true lags."""
    out = record.parent / "model.yaml"
    compd(*_fit_argv(record, "T1,T2", out, "--method", "oe", "--order", 1))
    return out


def _compare_json(model: Path, data: Path, *options: object) -> dict:
    return json.loads(compd("compare", model, data, "--json", *options))


def _tfs(path: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    subs = load_model(path).model.outputs[0].submodels
    return [(np.asarray(s.tf.num), np.asarray(s.tf.den)) for s in subs]


def test_compare_from_judges_the_window_of_a_whole_file_run(model: Path, record: Path) -> None:
    """``compare --from`` gives the metrics of the window of a simulation run from the file's start."""
    summary = _compare_json(model, record, "--from", "32:00")
    data = load_data(record)
    start = int(CUT_S / TS)
    expected = Comparison.of(
        OUTPUT,
        data.column(OUTPUT)[start:],
        evaluate(load_model(model), data).predicted(OUTPUT)[start:],
    )
    judged = summary["outputs"][OUTPUT]
    assert judged["fit_percent"] == pytest.approx(expected.fit_percent, rel=1e-12)
    assert judged["rms_um"] == pytest.approx(expected.residue.rms_um, rel=1e-12)
    assert judged["uncompensated_rms_um"] == pytest.approx(expected.uncompensated.rms_um)
    assert summary["samples"] == data.time_s.size - start
    assert (summary["from_s"], summary["until_s"]) == (CUT_S, None)


def test_compare_from_is_not_a_split_file(model: Path, record: Path, tmp_path: Path) -> None:
    """A split-off file resets every reference and the model state; ``--from`` keeps the whole log's."""
    frame = _record()
    split = _write(frame[frame.time_s >= CUT_S], tmp_path / "rest.csv")
    on_window = _compare_json(model, record, "--from", CUT_S)["outputs"][OUTPUT]
    on_split = _compare_json(model, split)["outputs"][OUTPUT]
    assert on_window["fit_percent"] > 95.0
    assert on_split["fit_percent"] < on_window["fit_percent"] - 20.0


def test_compare_until_and_from_print_the_window(model: Path, record: Path) -> None:
    """The table output says which hours were judged and that the model ran from the file's start."""
    printed = compd("compare", model, record, "--from", "8:00", "--until", 115200)
    assert f"judged on 8.00 h .. 31.98 h (1440 samples) of {record}" in printed
    assert "model run from the file's start" in printed


@pytest.mark.parametrize("method", ["mlr", "arx", "oe"])
def test_fit_until_reads_nothing_after_the_cut(method: str, tmp_path: Path) -> None:
    """``fit --until X`` writes the same model whatever the file holds after X."""
    fitted = []
    for shift in (0.0, 4.0):
        data = _write(_record(after_cut=shift), tmp_path / f"log{shift:g}.csv")
        out = tmp_path / f"{method}{shift:g}.yaml"
        compd(*_fit_argv(data, "T1,T2", out, "--method", method, "--order", 1, "--until", "32:00"))
        fitted.append(_tfs(out))
    for (num, den), (num2, den2) in zip(*fitted, strict=True):
        np.testing.assert_array_equal(num, num2)
        np.testing.assert_array_equal(den, den2)


def test_fit_from_fits_the_window_with_the_whole_log_references(tmp_path: Path) -> None:
    """``fit --from X`` ignores the measured output before X yet recovers the lags run from the start."""
    frame = _record()
    spoiled = frame.copy()
    spoiled.loc[spoiled.time_s < 8 * 3600.0, OUTPUT] = 1e3  # never fitted: must not matter
    models = []
    for name, table in (("clean", frame), ("spoiled", spoiled)):
        out = tmp_path / f"{name}.yaml"
        compd(
            *_fit_argv(
                _write(table, tmp_path / f"{name}.csv"),
                "T1,T2",
                out,
                "--method",
                "oe",
                "--order",
                1,
                "--from",
                "8:00",
            )
        )
        models.append(out)
    for (num, den), (num2, den2) in zip(_tfs(models[0]), _tfs(models[1]), strict=True):
        np.testing.assert_allclose(num, num2, rtol=1e-9)
        np.testing.assert_allclose(den, den2, rtol=1e-9)
    gains = [s.tf.static_gain() for s in load_model(models[1]).model.outputs[0].submodels]
    np.testing.assert_allclose(gains, [3.0, -1.0], rtol=0.02)


def test_fit_from_until_records_the_window(record: Path, tmp_path: Path) -> None:
    """The model's calibration record covers the fitted samples only, and the output names them."""
    out = tmp_path / "m.yaml"
    printed = compd(
        *_fit_argv(record, "T1,T2", out, "--method", "mlr", "--from", "8:00", "--until", "32:00")
    )
    assert "fitted on 8.00 h .. 31.98 h (1440 samples)" in printed
    provenance = load_model(out).doc.provenance
    assert provenance.calibration is not None
    assert provenance.calibration.samples == 1440
    assert "fitted on 8.00 h .. 31.98 h" in provenance.notes


def test_diagnose_and_extend_take_the_window(model: Path, record: Path, tmp_path: Path) -> None:
    """``diagnose`` and ``extend`` accept ``--from``/``--until`` and echo them in their JSON."""
    diagnosis = json.loads(
        compd("diagnose", model, record, "--candidates", "spindle_*", "--from", "16:00", "--json")
    )
    assert diagnosis["from_s"] == 16 * 3600.0
    assert [c["signal"] for c in diagnosis["candidates"]] == ["spindle_speed_rpm"]
    extension = json.loads(
        compd(
            "extend",
            model,
            record,
            "--effect",
            "spindle_speed_rpm",
            "--out",
            tmp_path / "x.yaml",
            "--order",
            1,
            "--until",
            "32:00",
            "--json",
            "--force",  # the model already fits: the signal adds nothing, but the window is the point
        )
    )
    assert (extension["from_s"], extension["until_s"]) == (None, CUT_S)


def test_report_from_says_what_it_judged(model: Path, record: Path, tmp_path: Path) -> None:
    """``report --from`` writes a page that names the judged hours."""
    out = tmp_path / "r.html"
    compd("report", model, record, "--from", "32:00", "--out", out)
    assert "judged on 32.00 h .. 47.98 h of the record" in out.read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (("--from", "32:00", "--until", "8:00"), ["--from 32:00 is not before --until 8:00"]),
        (("--from", "50:00"), ["--from 50:00", "outside the record", "0 .. 48:00"]),
        (("--from", "47:59"), ["fewer than the 50 needed", "--from"]),
    ],
)
def test_bad_windows_are_input_errors(
    options: tuple[str, ...],
    words: list[str],
    record: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A window that is empty, outside the record or too short ends with status 2 and names the span."""
    assert main(_fit_argv(record, "T1", tmp_path / "m.yaml", *options)) == 2
    err = capsys.readouterr().err
    for word in words:
        assert word in err
    assert not (tmp_path / "m.yaml").exists()


def test_a_time_that_is_not_one_is_a_usage_error(model: Path, record: Path) -> None:
    """``--from 32h`` is refused by the parser, which shows the accepted forms."""
    with pytest.raises(SystemExit) as stop:
        main(["compare", str(model), str(record), "--from", "32h"])
    assert stop.value.code == 2


def _fit_argv(record: Path, inputs: str, out: Path, *options: object) -> list[str]:
    """``compd fit`` of the record's output from ``inputs`` into ``out``."""
    argv = ["fit", "--data", record, "--output", OUTPUT, "--inputs", inputs, "--out", out]
    return [str(a) for a in (*argv, *options)]


@pytest.mark.parametrize(
    ("inputs", "signals"),
    [
        ("T*", ("T1", "T2")),
        ("all", ("T1", "T2", "spindle_speed_rpm")),
        ("T2,spindle_*", ("T2", "spindle_speed_rpm")),
        ("T1,T*", ("T1", "T2")),
    ],
)
def test_inputs_take_globs_and_all(
    inputs: str, signals: tuple[str, ...], record: Path, tmp_path: Path
) -> None:
    """``--inputs`` expands globs and ``all`` (never the output or another displacement) in column order."""
    out = tmp_path / "m.yaml"
    compd(*_fit_argv(record, inputs, out, "--method", "mlr"))
    assert load_model(out).model.signals() == signals


def test_a_pattern_matching_nothing_is_an_error(
    record: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A glob that matches no column names itself, the option and the file's columns."""
    assert main(_fit_argv(record, "T1,temp_*", tmp_path / "m.yaml")) == 2
    err = capsys.readouterr().err
    assert "'temp_*' matches no column" in err
    assert "--inputs" in err
    assert "spindle_speed_rpm" in err


def test_residual_from_fits_the_forest_on_the_window(model: Path, tmp_path: Path) -> None:
    """``residual --from`` judges the model alone on the window of a run from the file's start."""
    frame = _record()
    frame["door_open"] = ((frame.time_s % 5400.0) < 600.0).astype(float)
    data = _write(frame, tmp_path / "door.csv")
    summary = json.loads(
        compd(
            "residual",
            model,
            data,
            "--from",
            "32:00",
            "--trees",
            5,
            "--out",
            tmp_path / "stacked.yaml",
            "--json",
        )
    )
    loaded = load_data(data)
    start = int(CUT_S / TS)
    residue = loaded.column(OUTPUT) - evaluate(load_model(model), loaded).predicted(OUTPUT)
    assert summary["from_s"] == CUT_S
    assert summary["data"]["model_alone"]["rms_um"] == pytest.approx(
        float(np.sqrt(np.mean(residue[start:] ** 2))), rel=1e-12
    )


def test_diagnose_candidates_all_is_every_signal_but_displacements(
    model: Path, record: Path
) -> None:
    """``diagnose --candidates all`` tests the model's inputs too, never a displacement column."""
    diagnosis = json.loads(compd("diagnose", model, record, "--candidates", "all", "--json"))
    assert {c["signal"] for c in diagnosis["candidates"]} == {"T1", "T2", "spindle_speed_rpm"}
    assert (diagnosis["from_s"], diagnosis["until_s"]) == (None, None)
