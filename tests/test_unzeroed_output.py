"""A displacement logged without zeroing at the file's start is taken as its change from there, and said so.

Every model predicts the displacement's change since the record's start.
Before, a file whose displacement began at 10 um (a gauge read as it was, a
file split off a longer log) was fitted into a model of -74 % on its own
calibration and judged at -1964 %, without a word about why.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compd.files.data import load_data
from compd.files.modelfile import parse_model
from compd.model.outputstart import unzeroed_start
from compd.toolkit.evaluate import compare, evaluate
from compd.toolkit.fit import FitRequest, fit_data
from tests.clirun import compd, compd_result

REAL_RECORD = Path(__file__).parent / "data" / "fl_thermal_train.csv"
OFFSET_UM = 10.0


def write_record(path: Path, offset_um: float = 0.0, seed: int = 0) -> Path:
    """6 h at 60 s: T1 warms by 5 degC, the displacement follows through a 30 min lag (exactly 0 at the start)."""
    rng = np.random.default_rng(seed)
    n = 360
    t1 = 20.0 + 5.0 * (1.0 - np.exp(-np.arange(n) / 90.0)) + rng.normal(0.0, 0.01, n)
    lagged = np.zeros(n)
    for k in range(1, n):
        lagged[k] = lagged[k - 1] + (t1[k - 1] - 20.0 - lagged[k - 1]) / 30.0
    disp = 3.0 * lagged + rng.normal(0.0, 0.05, n)
    disp[0] = 0.0
    frame = pd.DataFrame({"time_s": np.arange(n) * 60.0, "T1": t1, "disp_z_um": disp + offset_um})
    frame.to_csv(path, index=False)
    return path


def test_a_zeroed_record_is_left_as_logged() -> None:
    rng = np.random.default_rng(1)
    drift = np.linspace(0.0, 20.0, 500) + rng.normal(0.0, 0.1, 500)
    assert unzeroed_start(drift) is None


def test_a_record_that_starts_far_from_zero_is_found() -> None:
    rng = np.random.default_rng(1)
    drift = np.linspace(0.0, 5.0, 500) + rng.normal(0.0, 0.1, 500)
    assert unzeroed_start(drift + OFFSET_UM) == pytest.approx(drift[0] + OFFSET_UM)


def test_the_shared_real_record_starts_zeroed_on_every_channel() -> None:
    frame = pd.read_csv(REAL_RECORD)
    for channel in range(1, 6):
        assert unzeroed_start(frame[f"disp_ch{channel}_um"].to_numpy()) is None


def test_fit_takes_an_unzeroed_output_as_its_change_and_fits_the_same_model(
    tmp_path: Path,
) -> None:
    zeroed = fit_data(
        load_data(write_record(tmp_path / "zeroed.csv")),
        FitRequest(output="disp_z_um", inputs=["T1"]),
    )
    offset = fit_data(
        load_data(write_record(tmp_path / "offset.csv", OFFSET_UM)),
        FitRequest(output="disp_z_um", inputs=["T1"]),
    )
    assert offset.identification.method == zeroed.identification.method
    assert offset.comparison.fit_percent == pytest.approx(zeroed.comparison.fit_percent)
    assert offset.comparison.fit_percent > 90.0
    assert zeroed.notes == ()
    assert "offset.csv: disp_z_um starts at 10 um, not at 0" in offset.notes[0]
    assert "not zeroed at the start of" in offset.provenance.notes


def test_compare_judges_an_unzeroed_file_as_the_zeroed_one_and_says_so(tmp_path: Path) -> None:
    model_path = tmp_path / "model.yaml"
    calibration = write_record(tmp_path / "calibration.csv")
    compd(
        "fit", "--data", calibration, "--output", "disp_z_um", "--inputs", "T1",
        "--out", model_path,
    )  # fmt: skip
    model = parse_model(model_path.read_text())
    zeroed = write_record(tmp_path / "zeroed.csv", seed=2)
    offset = write_record(tmp_path / "offset.csv", OFFSET_UM, seed=2)
    (as_zeroed,) = compare(evaluate(model, load_data(zeroed)))
    (as_offset,) = compare(evaluate(model, load_data(offset)))
    assert as_offset.fit_percent == pytest.approx(as_zeroed.fit_percent)
    assert as_offset.residue.rms_um == pytest.approx(as_zeroed.residue.rms_um)
    code, _, err = compd_result("compare", model_path, offset)
    assert code == 0 and "disp_z_um starts at 10 um, not at 0" in err
    code, _, err = compd_result("compare", model_path, zeroed)
    assert code == 0 and "not at 0" not in err


def test_several_files_are_each_zeroed_at_their_own_start(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    write_record(runs / "01.csv", seed=3)
    write_record(runs / "02.csv", OFFSET_UM, seed=4)
    zeroed = tmp_path / "zeroed"
    zeroed.mkdir()
    write_record(zeroed / "01.csv", seed=3)
    write_record(zeroed / "02.csv", seed=4)
    for folder in (runs, zeroed):
        compd(
            "fit", "--data", folder, "--output", "disp_z_um", "--inputs", "T1",
            "--out", folder / "model.yaml",
        )  # fmt: skip
    record = load_data(zeroed / "01.csv")
    predicted = [
        evaluate(parse_model((f / "model.yaml").read_text()), record).predicted("disp_z_um")
        for f in (runs, zeroed)
    ]
    np.testing.assert_allclose(predicted[0], predicted[1], atol=1e-9)
    code, _, err = compd_result("compare", zeroed / "model.yaml", runs)
    assert code == 0 and "02.csv" in err and "starts at 10 um" in err
