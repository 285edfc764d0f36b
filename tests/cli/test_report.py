"""``compd report`` end to end on the bundled files."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from compd.cli import main

CONFIG = Path(__file__).parent.parent.parent / "config"
DATA = CONFIG / "example_spectrum.csv"
GATED = CONFIG / "example_gated_arx.yaml"
SEED000 = CONFIG / "seed000_hmc_tf.yaml"


def summary(html: str, element_id: str = "compd-summary") -> dict:
    found = re.search(
        rf'<script type="application/json" id="{element_id}">(.*?)</script>', html, re.S
    )
    assert found, element_id
    return json.loads(found.group(1))


def test_report_writes_one_html_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``compd report MODEL DATA --out FILE`` writes the page and says where and how big."""
    out = tmp_path / "report.html"
    assert main(["report", str(GATED), str(DATA), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "MB" in printed
    assert summary(out.read_text(encoding="utf-8"))["model"] == "example-gated-arx-y"


def test_report_options_reach_the_analysis(tmp_path: Path) -> None:
    """--output, --tolerance-um and --window-s are those compare uses, and the summary records them."""
    out = tmp_path / "report.html"
    argv = ["--output", "disp_y_um", "--tolerance-um", "1.5", "--window-s", "600"]
    assert main(["report", str(GATED), str(DATA), "--out", str(out), *argv]) == 0
    found = summary(out.read_text(encoding="utf-8"))
    assert found["window_s"] == 600.0
    assert found["outputs"]["disp_y_um"]["window_tolerance_um"] == 1.5
    assert found["failing_windows"], "a 1.5 um limit on a 1.8 um RMS residue finds windows"


def test_report_on_a_missing_column_is_an_input_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A measured column the data lacks ends with status 2, a message naming the file, and no file written."""
    out = tmp_path / "report.html"
    code = main(["report", str(SEED000), str(DATA), "--out", str(out), "--output", "disp_x_um"])
    assert code == 2
    assert "example_spectrum.csv" in capsys.readouterr().err
    assert not out.exists()


def test_compare_writes_the_same_report_beside_its_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``compare --json --report OUT`` prints the object the report embeds, figure for figure."""
    out = tmp_path / "compare.html"
    assert main(["compare", str(GATED), str(DATA), "--json", "--report", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert summary(out.read_text(encoding="utf-8")) == printed
