"""Reports written once per session from the bundled example files, shared by the report tests."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from compd.cli import main
from compd.files.data import DataSet

CONFIG = Path(__file__).parent.parent.parent / "config"
DATA = CONFIG / "example_spectrum.csv"
SEED000 = CONFIG / "seed000_hmc_tf.yaml"
REGRESSION = CONFIG / "seed000_linear_regression.yaml"
GATED = CONFIG / "example_gated_arx.yaml"

#: The regression baseline with a calibration and one extension in its provenance.
PROVENANCE = """
provenance:
  data: Horejs 2010, eq. 1
  command: compd fit (test fixture)
  calibration:
    data: calibration_run.csv
    samples: 2880
    sample_time_s: 10.0
    fit_percent: {disp_z_um: 65.2}
    rms_um: {disp_z_um: 12.59}
    ranges: {spindle_speed_rpm: [0.0, 3000.0], spindle_power_kw: [0.0, 3.0]}
  extensions:
    - parent_sha256: 0123456789abcdef
      data: extension_run.csv
      effect_signal: spindle_power_kw
      submodels: [cutting]
      fit_percent_before: {disp_z_um: 65.2}
      fit_percent_after: {disp_z_um: 81.4}
      created: "2026-11-23T05:00:00Z"
"""


def day_record() -> DataSet:
    """24 h at 1 Hz of spindle speed and power, two temperatures and a displacement, in memory.

    Shared with ``benchmarks/bench_report.py``, which times the report of it.
    """
    n = 86_400
    t = np.arange(n, dtype=float)
    rng = np.random.default_rng(7)
    speed = np.where((t // 3600) % 3 == 1, 6000.0, 0.0)
    spindle = 20.0 + np.convolve(speed / 600.0, np.exp(-np.arange(3000) / 900.0) / 900.0)[:n]
    shop = 20.0 + 0.8 * np.sin(2 * np.pi * t / 86_400.0)
    disp = 3.0 * (spindle - 20.0) + rng.normal(0.0, 0.3, n)
    columns = {
        "T_spindle_degC": spindle,
        "T_shopfloor_degC": shop,
        "spindle_speed_rpm": speed,
        "spindle_power_kw": speed / 1500.0 + rng.normal(0.0, 0.05, n),
        "disp_y_um": disp,
    }
    return DataSet("day.csv", t, 1.0, columns, None, ())


@dataclass(frozen=True)
class Written:
    """A report file and the ``compare --json`` objects of its models, from the CLI."""

    html_path: Path
    html: str
    summaries: tuple[dict, ...]
    models: tuple[Path, ...]


def cli_json(*argv: object) -> dict:
    """Run ``compd compare ... --json`` in-process and parse what it prints."""
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([str(a) for a in argv])
    assert code == 0
    return json.loads(out.getvalue())


def _write(out: Path, model: Path, other: Path | None = None, *options: str) -> Written:
    argv = ["report", str(model), str(DATA), "--out", str(out), *options]
    if other is not None:
        argv += ["--compare", str(other)]
    assert main(argv) == 0
    models = (model,) if other is None else (model, other)
    return Written(
        out,
        out.read_text(encoding="utf-8"),
        tuple(cli_json("compare", m, DATA, "--json", *options) for m in models),
        models,
    )


@pytest.fixture(scope="session")
def regression_with_provenance(tmp_path_factory: pytest.TempPathFactory) -> Path:
    text = REGRESSION.read_text(encoding="utf-8")
    text = text[: text.index("provenance:")] + PROVENANCE.lstrip("\n")
    path = tmp_path_factory.mktemp("models") / "regression_calibrated.yaml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def single_report(tmp_path_factory: pytest.TempPathFactory) -> Written:
    """The bundled gated ARX example on the bundled data, with a residue limit some windows exceed."""
    return _write(
        tmp_path_factory.mktemp("report") / "gated.html", GATED, None, "--tolerance-um", "2.5"
    )


@pytest.fixture(scope="session")
def compare_report(
    tmp_path_factory: pytest.TempPathFactory, regression_with_provenance: Path
) -> Written:
    """Horejs 2010's TF model against the controller's regression (with provenance), same data.

    Judged at 1 um RMS, so both models have failing windows, of several grades.
    """
    return _write(
        tmp_path_factory.mktemp("report") / "compare.html",
        SEED000,
        regression_with_provenance,
        "--tolerance-um",
        "1.0",
    )
