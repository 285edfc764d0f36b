"""Several data files as experiments: loaded alike, run and fitted with no continuity across files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from compd.errors import DataFileError
from compd.files.data import load_data
from compd.files.experiments import load_experiments, stack
from compd.files.modelfile import load_model
from compd.model.crossval import experiment_folds
from compd.toolkit.evaluate import evaluate
from compd.toolkit.fit import FitRequest, fit_data
from tests.clirun import compd

N = 1500
TS_S = 10.0


def write(path: Path, level_degC: float, seed: int, **extra: np.ndarray) -> Path:
    """A record whose displacement follows a first-order lag of the spindle temperature's change."""
    rng = np.random.default_rng(seed)
    speed = np.repeat(rng.integers(0, 3, N // 50), 50) * 4000.0
    temp = level_degC + np.cumsum(0.004 * (speed / 4000.0 - 0.9)) + rng.normal(0, 0.01, N)
    disp = np.zeros(N)
    for k in range(1, N):
        disp[k] = 0.98 * disp[k - 1] + 0.05 * (temp[k - 1] - temp[0])
    frame = {
        "time_s": np.arange(N) * TS_S,
        "T_spindle_degC": temp,
        "spindle_rpm": speed,
        "disp_z_um": disp + rng.normal(0, 0.02, N),
        **extra,
    }
    pd.DataFrame(frame).to_csv(path, index=False)
    return path


@pytest.fixture
def two(tmp_path: Path) -> list[Path]:
    """Two records of one machine, the second starting 8 degC warmer."""
    folder = tmp_path / "runs"
    folder.mkdir()
    return [write(folder / "a.csv", 20.0, 1), write(folder / "b.csv", 28.0, 2)]


def test_a_folder_is_its_files_sorted_by_name(two: list[Path]) -> None:
    """A folder reads as its CSV/Parquet files in name order, each a data set of its own."""
    (two[0].parent / "notes.txt").write_text("not data")
    experiments = load_experiments([two[0].parent])
    assert [e.path for e in experiments] == [str(p) for p in two]
    assert [len(e) for e in experiments] == [N, N]


def test_files_with_different_columns_are_refused_naming_file_and_column(
    two: list[Path], tmp_path: Path
) -> None:
    """A file without a column the others have: refused, naming that file and the column."""
    odd = write(tmp_path / "c.csv", 20.0, 3, T_ambient_degC=np.full(N, 21.0))
    with pytest.raises(DataFileError) as raised:
        load_experiments([*two, odd])
    assert str(two[0]) in str(raised.value) and "'T_ambient_degC'" in str(raised.value)
    assert str(odd) in str(raised.value)


def test_an_empty_folder_and_another_sample_time_are_refused(
    two: list[Path], tmp_path: Path
) -> None:
    """Nothing to read, or a file at another sample time: clear errors naming the place."""
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFileError, match="holds no data file"):
        load_experiments([tmp_path / "empty"])
    frame = pd.read_csv(two[1])
    frame["time_s"] *= 2
    frame.to_csv(tmp_path / "slow.csv", index=False)
    with pytest.raises(DataFileError, match="sample time is 20 s"):
        load_experiments([two[0], tmp_path / "slow.csv"])


def test_experiment_folds_leave_one_file_out() -> None:
    """Each experiment is a fold; beyond max_folds, neighbouring experiments share one."""
    folds = experiment_folds(10, [0, 3, 7])
    assert folds.labels.tolist() == [0, 0, 0, 1, 1, 1, 1, 2, 2, 2]
    many = experiment_folds(8, range(8), max_folds=4)
    assert many.n_folds == 4 and many.labels.tolist() == [0, 0, 1, 1, 2, 2, 3, 3]


@pytest.fixture
def model(two: list[Path], tmp_path: Path) -> Path:
    path = tmp_path / "m.yaml"
    compd("fit", "--data", two[0], "--output", "disp_z_um", "--inputs", "T_spindle_degC",
          "--method", "arx", "--order", "1", "--out", path)  # fmt: skip
    return path


def test_simulate_over_experiments_runs_each_file_from_its_start(
    two: list[Path], model: Path, tmp_path: Path
) -> None:
    """simulate over [a, b] equals a and b simulated alone; the concatenated file differs."""
    together = tmp_path / "together.csv"
    compd("simulate", model, *two, "--out", together)
    apart = [tmp_path / "a_pred.csv", tmp_path / "b_pred.csv"]
    for data, out in zip(two, apart, strict=True):
        compd("simulate", model, data, "--out", out)
    joined = pd.read_csv(together)
    alone = pd.concat([pd.read_csv(p) for p in apart], ignore_index=True)
    assert joined["experiment"].tolist() == [0] * N + [1] * N
    assert_allclose(joined["disp_z_um"], alone["disp_z_um"], atol=1e-6)
    # One file of both records end to end: the model carries a's state into b and
    # takes b's inputs as changes from a's first values, 8 degC off.
    frames = [pd.read_csv(p) for p in two]
    frames[1]["time_s"] += N * TS_S
    concatenated = tmp_path / "concatenated.csv"
    pd.concat(frames, ignore_index=True).to_csv(concatenated, index=False)
    continuous = evaluate(load_model(model), load_data(concatenated)).predicted("disp_z_um")
    assert np.max(np.abs(continuous[N:] - alone["disp_z_um"].to_numpy()[N:])) > 1.0


def test_compare_judges_each_file_and_pools_them(two: list[Path], model: Path) -> None:
    """compare --json over two files: one entry per file as compare gives it alone, and the pool."""
    import json

    both = json.loads(compd("compare", model, two[0].parent, "--json"))
    for entry, path in zip(both["experiments"], two, strict=True):
        alone = json.loads(compd("compare", model, path, "--json"))
        assert entry["data"] == str(path)
        assert entry["outputs"]["disp_z_um"] == pytest.approx(alone["outputs"]["disp_z_um"])
    assert set(both["pooled"]["outputs"]) == {"disp_z_um"}


def arx1_lstsq(paths: list[Path], inputs: list[str]) -> np.ndarray:
    """ARX(1, 1, 1) by numpy lstsq on the stacked regressions of each file: [a1, b_1, ...]."""
    rows, targets = [], []
    for path in paths:
        frame = pd.read_csv(path)
        y = frame["disp_z_um"].to_numpy()
        u = [frame[name].to_numpy() - frame[name].to_numpy()[0] for name in inputs]
        rows.append(np.column_stack([-y[:-1], *(x[:-1] for x in u)]))
        targets.append(y[1:])
    theta, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(targets), rcond=None)
    return np.asarray(theta)


def test_an_arx_fit_on_two_files_takes_no_lag_across_them(two: list[Path]) -> None:
    """ARX on [a, b] equals lstsq on each file's regressors stacked, not on the joined record."""
    inputs = ["T_spindle_degC", "spindle_rpm"]
    result = fit_data(
        load_experiments(two),
        FitRequest(output="disp_z_um", inputs=inputs, method="arx", order=1),
    )
    channels = result.identification.channels
    a1 = channels[0].tf.a[1]
    b = [c.tf.b[1] for c in channels]  # nk = 1: b = [0, b1]
    expected = arx1_lstsq(two, inputs)
    assert_allclose([a1, *b], expected, rtol=1e-6)
    # The joined record's lstsq (one row with a lag across the files, b's inputs referenced
    # to a's first values) is another model: the comparison above can tell them apart.
    joined = stack(load_experiments(two)).data
    frame = pd.DataFrame({name: joined.column(name) for name in [*inputs, "disp_z_um"]})
    frame.to_csv(two[0].parent.parent / "joined.csv", index=False)
    wrong = arx1_lstsq([two[0].parent.parent / "joined.csv"], inputs)
    assert not np.allclose(wrong, expected, rtol=1e-3)


def test_a_lag_bank_fit_on_two_files_leaves_one_file_out(two: list[Path]) -> None:
    """fit --method auto over two files: folds are the files; the lags restart at each."""
    result = fit_data(
        load_experiments(two),
        FitRequest(output="disp_z_um", inputs=["T_spindle_degC"], method="auto"),
    )
    assert result.selection is not None
    assert result.selection.folds.describe() == "leave one of 2 experiments (files) out"
    assert "2 experiments (files)" in result.provenance.notes


def test_options_of_one_record_are_refused_with_several(two: list[Path]) -> None:
    """OE and ARX order search work on one record: refused with the fix."""
    experiments = load_experiments(two)
    with pytest.raises(DataFileError, match="--method oe works on one record"):
        fit_data(
            experiments, FitRequest(output="disp_z_um", inputs=["T_spindle_degC"], method="oe")
        )
    with pytest.raises(DataFileError, match="give the order"):
        fit_data(
            experiments, FitRequest(output="disp_z_um", inputs=["T_spindle_degC"], method="arx")
        )


def test_a_one_row_file_in_a_folder_is_left_out_with_a_note(two: list[Path]) -> None:
    """A recorder stopped right after rotating leaves a one-row file: not an experiment, noted."""
    short = two[0].parent / "c.csv"
    short.write_text("# machine_id: m1\ntime_s,T_spindle_degC,spindle_rpm,disp_z_um\n0,20,0,0\n")
    experiments = load_experiments([two[0].parent])
    assert [e.path for e in experiments] == [str(p) for p in two]
    assert any(f"left out {short}: 1 row(s)" in note for note in experiments[0].notes)
    with pytest.raises(DataFileError, match="1 data row"):  # named on its own: refused
        load_experiments([*two, short])
