"""Position-dependent feed-axis errors end to end through the CLI, on twin data with a growing X ball screw.

The twin's ``feed_positions`` run moves the X axis among eight positions
while rapid motion heats its ball screw, so the X error at the TCP is
``slope(T_screw) * X + offset``. A plain TF model (no position term) can only
fit the position-averaged error; ``compd fit --position X_position_mm`` adds
one slope sub-model per input. Both are fitted on one run and compared on a
second run with another seed. Measured (24 h calibration, 16 h check run,
10 s sampling, seeds 1 and 2):

=========  ==================================  ===============  ============  ===========
method     inputs                              fit % plain/pos  RMS um        p-p um
=========  ==================================  ===============  ============  ===========
OE         screw T, headstock T, ambient T     28.0 / 94.8      5.85 / 0.43   29.0 / 3.5
ARX        feed rate, headstock T, ambient T   23.3 / 93.6      6.24 / 0.52   28.7 / 2.8
=========  ==================================  ===============  ============  ===========

Uncompensated: RMS 12.0 um, peak-to-peak 34.7 um. The thresholds (>= 40
points more, >= 85 % fit, RMS and peak-to-peak at least halved) sit far
below those gains and far above anything the plain model can
reach by a better order: its error is the slope term itself, which no
position-free model can follow as the axis moves.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from compd.files.modelfile import load_model
from compd.sim.positions import simulate_feed_positions
from compd.toolkit.fitmodel import unit_of
from tests.clirun import compd_result as compd

SAMPLE_TIME_S = 10
CALIBRATION_HOURS = 24
RUN_HOURS = 16
OTHERS = "T_headstock_degC,T_ambient_degC"


def compare(model: Path, data: Path) -> dict[str, float]:
    code, out, err = compd("compare", model, data, "--output", "disp_x_um", "--json")
    assert code == 0, err
    report = json.loads(out)["outputs"]["disp_x_um"]
    return {key: float(report[key]) for key in ("fit_percent", "rms_um", "peak_to_peak_um")}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("positions")
    paths = []
    for hours, seed in ((CALIBRATION_HOURS, 1), (RUN_HOURS, 2)):
        path = folder / f"feed_positions-{seed}.csv"
        frame = simulate_feed_positions(hours, seed=seed, sample_time_s=SAMPLE_TIME_S)
        frame.to_csv(path, index=False, float_format="%.6f")
        paths.append(path)
    return paths[0], paths[1]


@pytest.mark.parametrize(
    ("method", "slope_input"),
    [("oe", "T_x_screw_degC"), ("arx", "feed_x_mm_per_min")],
    ids=["oe-screw-temperature", "arx-feed-rate"],
)
def test_position_term_beats_the_plain_model_on_an_unseen_run(
    runs: tuple[Path, Path], tmp_path: Path, method: str, slope_input: str
) -> None:
    """With --position the X model fits an unseen run >= 85 %, >= 40 points above the plain TF model."""
    calibration, unseen = runs
    inputs = f"{slope_input},{OTHERS}"
    common = (
        "--data",
        calibration,
        "--output",
        "disp_x_um",
        "--inputs",
        inputs,
        "--method",
        method,
    )
    plain, positioned = tmp_path / "plain.yaml", tmp_path / "position.yaml"
    assert compd("fit", *common, "--out", plain)[0] == 0
    code, printed, err = compd("fit", *common, "--position", "X_position_mm", "--out", positioned)
    assert code == 0, err
    assert "X_position_mm - 0 mm" in printed  # the slope sub-models are listed with their factor
    before, after = compare(plain, unseen), compare(positioned, unseen)
    assert after["fit_percent"] >= 85.0, (before, after)
    assert after["fit_percent"] - before["fit_percent"] >= 40.0, (before, after)
    assert after["rms_um"] <= 0.5 * before["rms_um"], (before, after)
    assert after["peak_to_peak_um"] <= 0.5 * before["peak_to_peak_um"], (before, after)
    # What fit prints for the calibration data is what the written file does there.
    recorded = load_model(positioned).doc.provenance.fit_percent["disp_x_um"]
    assert compare(positioned, calibration)["fit_percent"] == pytest.approx(recorded, abs=1e-6)


def test_fit_refuses_a_position_that_never_changes(runs: tuple[Path, Path], tmp_path: Path) -> None:
    """A position column with one value exits 2 naming the file, the column and the fix."""
    calibration, _ = runs
    out = tmp_path / "model.yaml"
    one_position = tmp_path / "one-position.csv"
    text = calibration.read_text().splitlines()
    header = text[0].split(",")
    column = header.index("X_position_mm")
    rows = [
        ",".join([*r.split(",")[:column], "250.0", *r.split(",")[column + 1 :]]) for r in text[1:]
    ]
    one_position.write_text("\n".join([text[0], *rows]) + "\n")
    code, _, err = compd(
        "fit", "--data", one_position, "--output", "disp_x_um", "--inputs", "T_x_screw_degC",
        "--position", "X_position_mm", "--out", out,
    )  # fmt: skip
    assert code == 2
    assert str(one_position) in err and "X_position_mm" in err
    assert "two or more positions" in err
    assert not out.exists()


def test_check_config_accepts_a_position_model_when_the_signal_is_defined(
    runs: tuple[Path, Path], tmp_path: Path
) -> None:
    """The daemon reads the position like any signal: check-config wants it defined, and then accepts the model."""
    calibration, _ = runs
    model = tmp_path / "x.yaml"
    assert compd(
        "fit", "--data", calibration, "--output", "disp_x_um", "--inputs", "T_x_screw_degC",
        "--method", "arx", "--order", "1", "--position", "X_position_mm", "--out", model,
    )[0] == 0  # fmt: skip

    def config(signals: tuple[str, ...]) -> Path:
        lines = [
            "schema: compd.config/1",
            f"model: {model}",
            "period_s: 10.0",
            "drivers:",
            "  machine:",
            "    type: simulated",
            f"    settings: {{data: {calibration}, loop: true}}",
            "signals:",
        ]
        for name in signals:
            # Each signal in the unit the model reads it in (its name's suffix, as fit took it).
            lines += [f"  {name}: {{driver: machine, address: {name}, unit: '{unit_of(name)}'}}"]
        lines += [
            "outputs:",
            "  X: {model_output: disp_x_um, driver: machine, address: comp_x_um, sign: -1,",
            "      max_offset_um: 50, max_rate_um_per_s: 1.0}",
            "status: {driver: machine, status_address: st, heartbeat_address: hb}",
            f"state: {{directory: {tmp_path / 'state'}}}",
        ]
        path = tmp_path / f"config-{len(signals)}.yaml"
        path.write_text("\n".join(lines) + "\n")
        return path

    code, _, err = compd("check-config", config(("T_x_screw_degC",)))
    assert code == 2 and "X_position_mm" in err
    code, out, err = compd("check-config", config(("T_x_screw_degC", "X_position_mm")))
    assert code == 0, err
    assert "ok" in out
