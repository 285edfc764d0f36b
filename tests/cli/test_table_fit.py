"""A table wider than the terminal is fitted to it without a word cut: headers wrap, or rows stack."""

from __future__ import annotations

import io

import pytest
from rich.console import Console
from rich.table import Table

from compd.cli import main
from compd.cli.tablefit import fit_table
from tests.residue_case import write_case

HEADERS = (
    "output", "fit %", "residue RMS", "residue p-p", "max |residue|",
    "uncomp. RMS", "uncomp. p-p", "RMS reduction", "p-p reduction",
)  # fmt: skip
ROW = ("disp_z_um", "33.6", "13.07", "34.15", "32.80", "53.56", "102.62", "75.6 %", "66.7 %")


def printed(width: int) -> str:
    """compare's summary table (as the README's loop prints it) fitted to ``width`` columns."""
    table = Table(*HEADERS, title="disp_z_um-lagbank vs cutting.csv; errors in um")
    table.add_row(*ROW)
    out = Console(width=width, record=True, file=io.StringIO())
    out.print(fit_table(table, out))
    return out.export_text()


@pytest.mark.parametrize("width", [140, 100, 80, 60])
def test_no_header_or_cell_is_cut_at_any_width(width: int) -> None:
    """Every word of every header and cell is printed whole, and no line is wider than the terminal."""
    text = printed(width)
    assert "…" not in text
    assert max(len(line) for line in text.splitlines()) <= width
    words = set(text.split())
    for cell in (*HEADERS, *ROW):
        assert set(cell.split()) <= words, cell


def test_at_100_columns_the_headers_wrap_between_words_in_one_table() -> None:
    """At 100 columns the nine columns stay side by side, ``max |residue|`` on two lines."""
    text = printed(100)
    assert "disp_z_um" in text and "|residue|" in text and "reduction" in text
    assert any(line.startswith("┏") for line in text.splitlines())


def test_too_narrow_for_the_longest_words_each_row_is_a_list() -> None:
    """At 60 columns each row is printed as header: value pairs, the title above."""
    lines = printed(60).splitlines()
    assert lines[0].startswith("disp_z_um-lagbank vs cutting.csv")
    assert any(line.split() == ["max", "|residue|", "32.80"] for line in lines), lines


def test_compare_at_100_columns_cuts_nothing(tmp_path, capsys, monkeypatch) -> None:
    """compd compare at COLUMNS=100: the summary and windows tables fit, no header cut."""
    model, data = write_case(tmp_path)
    monkeypatch.setenv("COLUMNS", "100")
    assert main(["compare", str(model), str(data)]) == 0
    out = capsys.readouterr().out
    assert "…" not in out and max(len(line) for line in out.splitlines()) <= 100
    assert "reduction" in out and "|residue|" in out


@pytest.mark.parametrize(
    "argv",
    [
        ["model", "check", "bundled:simulated_model.yaml"],
        ["check-config", "bundled:simulated.yaml"],
    ],
)
@pytest.mark.parametrize("columns", [100, 80])
def test_model_check_and_check_config_cut_nothing(capsys, monkeypatch, argv, columns) -> None:
    """The sub-model table and what the sensors cannot verify fit COLUMNS, no word cut (…)."""
    monkeypatch.setenv("COLUMNS", str(columns))
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "…" not in out and max(len(line) for line in out.splitlines()) <= columns
