"""Golden cases: each folder under tests/golden holds a README sentence, a command and its expected output.

Regenerate a case deliberately with ``COMPD_REGOLD=1 python -m pytest tests/test_golden.py``
and review the diff: a changed figure is a changed model result.
"""

import json
import os
import shlex
from pathlib import Path

import pytest

from compd.cli import main

GOLDEN = Path(__file__).parent / "golden"
ROOT = Path(__file__).parent.parent
CASES = sorted(p for p in GOLDEN.iterdir() if (p / "command").exists())
VOLATILE = {"data", "model_sha256"}  # absolute paths and file hashes differ between checkouts


def figures(report: dict) -> dict:
    return {key: value for key, value in report.items() if key not in VOLATILE}


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_golden_case(
    case: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The command's JSON output equals the stored expected.json (figures to 1e-7 relative, across BLAS builds)."""
    monkeypatch.chdir(ROOT)
    assert main(shlex.split((case / "command").read_text())) == 0
    actual = figures(json.loads(capsys.readouterr().out))
    expected_path = case / "expected.json"
    if os.environ.get("COMPD_REGOLD"):
        expected_path.write_text(json.dumps(actual, indent=2, sort_keys=True) + "\n")
    expected = json.loads(expected_path.read_text())
    assert set(actual["outputs"]) == set(expected["outputs"])
    for output, values in expected.pop("outputs").items():
        assert actual["outputs"][output] == pytest.approx(values, rel=1e-7, abs=1e-9), output
    assert {k: v for k, v in actual.items() if k != "outputs"} == expected
