"""What the commands print is the text as written: paths and names with brackets or colons are never markup or emoji."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from compd.cli import main

GATED = Path(__file__).parents[2] / "config" / "example_gated_arx.yaml"


def test_model_check_prints_a_path_and_a_name_with_brackets_and_colons_literally(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder named [bold]run and a model named '[/x] :100:' are shown as they are: no style eaten, no crash."""
    folder = tmp_path / "[bold]run"
    folder.mkdir()
    model = folder / "m.yaml"
    text = GATED.read_text()
    name = re.search(r"^name: (.*)$", text, re.MULTILINE)
    assert name is not None
    model.write_text(text.replace(name[0], "name: '[/x] :100:'"))
    code = main(["model", "check", str(model)])
    out = capsys.readouterr().out
    assert code == 0
    assert str(model) in out and "[/x] :100:" in out and "\N{HUNDRED POINTS SYMBOL}" not in out
